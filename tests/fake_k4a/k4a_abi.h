/* The slice of the Azure Kinect SDK ABI that skelfuse's ctypes binding touches, written from the SDK
 * headers (k4a/k4atypes.h 1.4, k4abt/k4abttypes.h 1.0 and 1.1+). Layouts must match the real SDK:
 * the fakes built from this header stand in for libk4a / libk4abt in the test suite.
 *
 * FAKE_K4ABT_ABI selects the body-tracking SDK generation: 10 = 1.0.x (tracker configuration
 * {sensor_orientation, cpu_only_mode (bool), gpu_device_id}; k4abt_frame_get_timestamp_usec),
 * 11 = 1.1+ ({sensor_orientation, processing_mode, gpu_device_id, model_path};
 * k4abt_frame_get_device_timestamp_usec and k4abt_frame_get_system_timestamp_nsec).
 */
#ifndef SKELFUSE_FAKE_K4A_ABI_H
#define SKELFUSE_FAKE_K4A_ABI_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#ifndef FAKE_K4ABT_ABI
#define FAKE_K4ABT_ABI 11
#endif

#if defined(_WIN32)
#define FAKE_EXPORT __declspec(dllexport)
#else
#define FAKE_EXPORT __attribute__((visibility("default")))
#endif

/* K4A_DECLARE_HANDLE(name): typedef struct _name { size_t _rsvd; } * name; */
typedef struct _k4a_device_t { size_t _rsvd; } *k4a_device_t;
typedef struct _k4a_capture_t { size_t _rsvd; } *k4a_capture_t;
typedef struct _k4abt_tracker_t { size_t _rsvd; } *k4abt_tracker_t;
typedef struct _k4abt_frame_t { size_t _rsvd; } *k4abt_frame_t;

/* k4atypes.h */
typedef enum { K4A_RESULT_SUCCEEDED = 0, K4A_RESULT_FAILED } k4a_result_t;
typedef enum { K4A_BUFFER_RESULT_SUCCEEDED = 0, K4A_BUFFER_RESULT_FAILED, K4A_BUFFER_RESULT_TOO_SMALL } k4a_buffer_result_t;
typedef enum { K4A_WAIT_RESULT_SUCCEEDED = 0, K4A_WAIT_RESULT_FAILED, K4A_WAIT_RESULT_TIMEOUT } k4a_wait_result_t;
#define K4A_WAIT_INFINITE (-1)

typedef union {
    struct { float x; float y; float z; } xyz;
    float v[3];
} k4a_float3_t;

typedef union {
    struct { float x; float y; } xy;
    float v[2];
} k4a_float2_t;

typedef struct { uint32_t major; uint32_t minor; uint32_t iteration; } k4a_version_t;
typedef enum { K4A_FIRMWARE_BUILD_RELEASE, K4A_FIRMWARE_BUILD_DEBUG } k4a_firmware_build_t;
typedef enum { K4A_FIRMWARE_SIGNATURE_MSFT, K4A_FIRMWARE_SIGNATURE_TEST, K4A_FIRMWARE_SIGNATURE_UNSIGNED } k4a_firmware_signature_t;
typedef struct {
    k4a_version_t rgb;
    k4a_version_t depth;
    k4a_version_t audio;
    k4a_version_t depth_sensor;
    k4a_firmware_build_t firmware_build;
    k4a_firmware_signature_t firmware_signature;
} k4a_hardware_version_t;

/* k4a_calibration_t, transcribed from k4atypes.h (Sensor SDK 1.4). The depth-level fusion builds one for its
 * virtual camera; the fake libk4abt reads the depth intrinsics from it, so a wrong layout shows. */
typedef enum {
    K4A_DEPTH_MODE_OFF = 0,
    K4A_DEPTH_MODE_NFOV_2X2BINNED,
    K4A_DEPTH_MODE_NFOV_UNBINNED,
    K4A_DEPTH_MODE_WFOV_2X2BINNED,
    K4A_DEPTH_MODE_WFOV_UNBINNED,
    K4A_DEPTH_MODE_PASSIVE_IR,
} k4a_depth_mode_t;
typedef enum { K4A_COLOR_RESOLUTION_OFF = 0 } k4a_color_resolution_t; /* 1..6: 720P .. 3072P */
typedef enum {
    K4A_CALIBRATION_TYPE_UNKNOWN = -1,
    K4A_CALIBRATION_TYPE_DEPTH,
    K4A_CALIBRATION_TYPE_COLOR,
    K4A_CALIBRATION_TYPE_GYRO,
    K4A_CALIBRATION_TYPE_ACCEL,
    K4A_CALIBRATION_TYPE_NUM,
} k4a_calibration_type_t;
typedef enum {
    K4A_CALIBRATION_LENS_DISTORTION_MODEL_UNKNOWN = 0,
    K4A_CALIBRATION_LENS_DISTORTION_MODEL_THETA,
    K4A_CALIBRATION_LENS_DISTORTION_MODEL_POLYNOMIAL_3K,
    K4A_CALIBRATION_LENS_DISTORTION_MODEL_RATIONAL_6KT,
    K4A_CALIBRATION_LENS_DISTORTION_MODEL_BROWN_CONRADY,
} k4a_calibration_model_type_t;
typedef struct _k4a_calibration_extrinsics_t {
    float rotation[9];
    float translation[3];
} k4a_calibration_extrinsics_t;
typedef union {
    struct _param {
        float cx, cy, fx, fy, k1, k2, k3, k4, k5, k6, codx, cody, p2, p1, metric_radius;
    } param;
    float v[15];
} k4a_calibration_intrinsic_parameters_t;
typedef struct _k4a_calibration_intrinsics_t {
    k4a_calibration_model_type_t type;
    unsigned int parameter_count;
    k4a_calibration_intrinsic_parameters_t parameters;
} k4a_calibration_intrinsics_t;
typedef struct _k4a_calibration_camera_t {
    k4a_calibration_extrinsics_t extrinsics;
    k4a_calibration_intrinsics_t intrinsics;
    int resolution_width;
    int resolution_height;
    float metric_radius;
} k4a_calibration_camera_t;
typedef struct _k4a_calibration_t {
    k4a_calibration_camera_t depth_camera_calibration;
    k4a_calibration_camera_t color_camera_calibration;
    k4a_calibration_extrinsics_t extrinsics[K4A_CALIBRATION_TYPE_NUM][K4A_CALIBRATION_TYPE_NUM];
    k4a_depth_mode_t depth_mode;
    k4a_color_resolution_t color_resolution;
} k4a_calibration_t;

/* Images (k4atypes.h): handles, formats, the release callback of k4a_image_create_from_buffer. */
typedef struct _k4a_image_t { size_t _rsvd; } *k4a_image_t;
typedef enum {
    K4A_IMAGE_FORMAT_COLOR_MJPG = 0,
    K4A_IMAGE_FORMAT_COLOR_NV12,
    K4A_IMAGE_FORMAT_COLOR_YUY2,
    K4A_IMAGE_FORMAT_COLOR_BGRA32,
    K4A_IMAGE_FORMAT_DEPTH16,
    K4A_IMAGE_FORMAT_IR16,
    K4A_IMAGE_FORMAT_CUSTOM8,
    K4A_IMAGE_FORMAT_CUSTOM16,
    K4A_IMAGE_FORMAT_CUSTOM,
} k4a_image_format_t;
typedef void(k4a_memory_destroy_cb_t)(void *buffer, void *context);

/* k4abttypes.h */
typedef enum {
    K4ABT_SENSOR_ORIENTATION_DEFAULT = 0,
    K4ABT_SENSOR_ORIENTATION_CLOCKWISE90,
    K4ABT_SENSOR_ORIENTATION_COUNTERCLOCKWISE90,
    K4ABT_SENSOR_ORIENTATION_FLIP180,
} k4abt_sensor_orientation_t;

typedef enum {
    K4ABT_TRACKER_PROCESSING_MODE_GPU = 0,
    K4ABT_TRACKER_PROCESSING_MODE_CPU,
    K4ABT_TRACKER_PROCESSING_MODE_GPU_CUDA,
    K4ABT_TRACKER_PROCESSING_MODE_GPU_TENSORRT,
    K4ABT_TRACKER_PROCESSING_MODE_GPU_DIRECTML
} k4abt_tracker_processing_mode_t;

#if FAKE_K4ABT_ABI >= 11
typedef struct _k4abt_tracker_configuration_t {
    k4abt_sensor_orientation_t sensor_orientation;
    k4abt_tracker_processing_mode_t processing_mode;
    int32_t gpu_device_id;
    const char *model_path;
} k4abt_tracker_configuration_t;
#else
typedef struct _k4abt_tracker_configuration_t {
    k4abt_sensor_orientation_t sensor_orientation;
    bool cpu_only_mode;
    int32_t gpu_device_id;
} k4abt_tracker_configuration_t;
#endif

typedef union {
    struct { float w; float x; float y; float z; } wxyz;
    float v[4];
} k4a_quaternion_t;

typedef enum {
    K4ABT_JOINT_CONFIDENCE_NONE = 0,
    K4ABT_JOINT_CONFIDENCE_LOW = 1,
    K4ABT_JOINT_CONFIDENCE_MEDIUM = 2,
    K4ABT_JOINT_CONFIDENCE_HIGH = 3,
    K4ABT_JOINT_CONFIDENCE_LEVELS_COUNT = 4,
} k4abt_joint_confidence_level_t;

#define K4ABT_JOINT_COUNT 32

typedef struct _k4abt_joint_t {
    k4a_float3_t position;
    k4a_quaternion_t orientation;
    k4abt_joint_confidence_level_t confidence_level;
} k4abt_joint_t;

typedef struct _k4abt_skeleton_t {
    k4abt_joint_t joints[K4ABT_JOINT_COUNT];
} k4abt_skeleton_t;

/* Written by the fake libk4a's k4a_capture_create into every capture, checked by the fake libk4abt: a
 * binding that passes the capsule pointer instead of the handle it points to is caught. */
#define FAKE_CAPTURE_MAGIC ((size_t)0x4B344143u) /* "K4AC" */
#define FAKE_IMAGE_MAGIC ((size_t)0x4B344149u) /* "K4AI" */

/* The fakes' own objects behind k4a_image_t / k4a_capture_t, shared by both fakes so that the fake tracker
 * can read the depth image of a capture the fake libk4a built (the real SDK's are opaque). */
typedef struct {
    size_t magic;
    int refcount;
    k4a_image_format_t format;
    int width, height, stride;
    uint8_t *buffer;
    size_t size;
    uint64_t device_usec;
    k4a_memory_destroy_cb_t *release;
    void *context;
} fake_image;

typedef struct {
    size_t magic;
    int refcount;
    fake_image *depth;
    fake_image *ir;
    /* Set by the fake libk4a's k4a_capture_create: the fake libk4abt keeps the capture a body frame came from
     * and makes the frame's body-index map through these, so that libk4a's counts of live captures and
     * images stay true across the two libraries (the real SDKs share one allocator the same way). */
    void (*release)(k4a_capture_t capture);
    k4a_result_t (*create_image)(k4a_image_format_t format, int width_pixels, int height_pixels, int stride_bytes,
                                 uint8_t *buffer, size_t buffer_size, k4a_memory_destroy_cb_t *buffer_release_cb,
                                 void *buffer_release_cb_context, k4a_image_t *image_handle);
} fake_capture;

#endif
