/* Fake libk4abt with the real ABI (k4a_abi.h), scripted by the test suite through the exported
 * fake_k4abt_* functions. Every enqueued capture consumes the next scripted event:
 *   FRAME            the capture is accepted; its body frame becomes ready to pop
 *   ENQUEUE_TIMEOUT  k4abt_tracker_enqueue_capture returns K4A_WAIT_RESULT_TIMEOUT (queue full)
 *   ENQUEUE_FAILED   ... returns K4A_WAIT_RESULT_FAILED
 *   POP_FAILED       the capture is accepted; the matching k4abt_tracker_pop_result returns FAILED
 *   DROP             the capture is accepted; its result never comes (pops time out)
 * With an empty script a capture yields a frame with no bodies. Ready results are queued up to
 * FAKE_QUEUE_MAX (the SDK's input queue is small); a full queue makes enqueue time out.
 * Waits never block for long: a pop on an empty queue sleeps min(timeout, 20 ms) and times out; an
 * infinite wait (K4A_WAIT_INFINITE) is counted in the stats and fails, since skelfuse must never use it.
 *
 * Faults for whole processes (the worker tests run skelfuse as a subprocess), from the environment variable
 * FAKE_K4ABT_FAULT, read at each pop: "KIND:AFTER[:TRACKERS]". Each tracker delivers AFTER results, then
 *   hang   its next k4abt_tracker_pop_result never returns (a hung SDK call; whatever its timeout), until
 *          fake_k4abt_release_hangs() or the process ends; a line on stderr says so, once per tracker
 *   stall  its pops time out from then on (a tracker that stopped producing results; captures still go in)
 * TRACKERS: only the first TRACKERS trackers created in the process get the fault (default: every one), so a
 * tracker created by a restart can be healthy.
 *
 * Process-wide behaviour from the environment, read at each k4abt_tracker_create (for trackers in processes
 * the test does not control directly):
 *   FAKE_K4ABT_ONE_TRACKER=1  a second live tracker in one process cannot be created (K4A_RESULT_FAILED), as
 *                             with Body Tracking SDK versions that allow one tracker per process
 *   FAKE_K4ABT_ECHO=1         echo mode on (fake_k4abt_set_echo)
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "k4a_abi.h"

#define FAKE_QUEUE_MAX 3
#define FAKE_SCRIPT_MAX 4096
#define FAKE_FRAME_MAGIC 0x4B344246u

enum { EV_FRAME = 0, EV_ENQUEUE_TIMEOUT = 1, EV_ENQUEUE_FAILED = 2, EV_POP_FAILED = 3, EV_DROP = 4 };

typedef struct {
    size_t magic;
    int refcount;
    int failed; /* a POP_FAILED marker, not a frame */
    uint64_t device_usec;
    uint64_t system_nsec;
    uint32_t n_bodies;
    uint32_t *ids;
    k4abt_skeleton_t *skeletons;
    fake_capture *capture; /* the capture the frame was computed from (one reference held), or NULL */
} fake_frame;

typedef struct {
    int kind;
    fake_frame *frame;
} fake_event;

typedef struct {
    size_t magic;
    int shutdown;
    k4a_calibration_t calibration;
    int index;      /* creation order in the process, from 0 */
    int delivered;  /* results popped */
    int hang_said;  /* the hang was reported on stderr */
} fake_tracker;

typedef struct {
    int32_t created;
    int32_t destroyed;
    int32_t shutdowns;
    int32_t frames_alive;
    int32_t infinite_waits;
    int32_t enqueued;
    int32_t popped;
    int32_t bad_captures;
    int32_t config_sensor_orientation;
    int32_t config_processing_mode; /* 1.0: cpu_only_mode */
    int32_t config_gpu_device_id;
    float smoothing;
    int32_t smoothing_calls;
    int32_t abi;
    const void *last_calibration;
    const void *last_capture;
    char model_path[512];
} fake_stats;

static fake_event g_script[FAKE_SCRIPT_MAX];
static int g_script_head = 0, g_script_len = 0;
static fake_frame *g_ready[FAKE_QUEUE_MAX];
static int g_ready_len = 0;
static int g_fail_creates = 0;
static int g_echo = 0;
static uint64_t g_auto_time = 0;
static fake_stats g_stats;
static int g_trackers_made = 0;
static int g_trackers_alive = 0;
static volatile int g_release_hangs = 0;

enum { FAULT_NONE = 0, FAULT_HANG = 1, FAULT_STALL = 2 };

/* The fault FAKE_K4ABT_FAULT sets for this tracker now (see the top of the file). */
static int fault_now(const fake_tracker *tracker) {
    const char *env = getenv("FAKE_K4ABT_FAULT");
    if (env == NULL || env[0] == '\0') return FAULT_NONE;
    char kind[16] = {0};
    int after = 0, trackers = 0;
    if (sscanf(env, "%15[a-z]:%d:%d", kind, &after, &trackers) < 2) return FAULT_NONE;
    if (trackers > 0 && tracker->index >= trackers) return FAULT_NONE;
    if (tracker->delivered < after) return FAULT_NONE;
    if (strcmp(kind, "hang") == 0) return FAULT_HANG;
    if (strcmp(kind, "stall") == 0) return FAULT_STALL;
    return FAULT_NONE;
}

static void nap_ms(int ms) {
    if (ms <= 0) return;
    if (ms > 20) ms = 20;
    struct timespec ts = {0, (long)ms * 1000000L};
    nanosleep(&ts, NULL);
}

static fake_frame *new_frame(uint64_t device_usec, uint64_t system_nsec, uint32_t n, const uint32_t *ids,
                             const k4abt_skeleton_t *skeletons) {
    fake_frame *frame = calloc(1, sizeof(fake_frame));
    frame->magic = FAKE_FRAME_MAGIC;
    frame->device_usec = device_usec;
    frame->system_nsec = system_nsec;
    frame->n_bodies = n;
    if (n > 0) {
        frame->ids = malloc(n * sizeof(uint32_t));
        frame->skeletons = malloc(n * sizeof(k4abt_skeleton_t));
        memcpy(frame->ids, ids, n * sizeof(uint32_t));
        memcpy(frame->skeletons, skeletons, n * sizeof(k4abt_skeleton_t));
    }
    return frame;
}

static void free_frame(fake_frame *frame) {
    frame->magic = 0;
    if (frame->capture != NULL) frame->capture->release((k4a_capture_t)frame->capture);
    free(frame->ids);
    free(frame->skeletons);
    free(frame);
}

/* ------------------------------------------------------------------ test control */

FAKE_EXPORT void fake_k4abt_reset(void) {
    for (int i = g_script_head; i < g_script_len; i++) if (g_script[i].frame) free_frame(g_script[i].frame);
    for (int i = 0; i < g_ready_len; i++) free_frame(g_ready[i]);
    g_script_head = g_script_len = g_ready_len = 0;
    g_fail_creates = 0;
    g_echo = 0;
    g_auto_time = 0;
    g_trackers_made = 0;
    int alive = g_stats.frames_alive; /* frames the binding still holds stay counted */
    memset(&g_stats, 0, sizeof(g_stats));
    g_stats.frames_alive = alive;
    g_stats.abi = FAKE_K4ABT_ABI;
}

FAKE_EXPORT int fake_k4abt_script_frame(uint64_t device_usec, uint64_t system_nsec, uint32_t n_bodies,
                                        const uint32_t *ids, const k4abt_skeleton_t *skeletons) {
    if (g_script_len >= FAKE_SCRIPT_MAX) return -1;
    g_script[g_script_len].kind = EV_FRAME;
    g_script[g_script_len].frame = new_frame(device_usec, system_nsec, n_bodies, ids, skeletons);
    return g_script_len++;
}

FAKE_EXPORT int fake_k4abt_script_event(int kind) {
    if (g_script_len >= FAKE_SCRIPT_MAX || kind < 1 || kind > 4) return -1;
    g_script[g_script_len].kind = kind;
    g_script[g_script_len].frame = NULL;
    return g_script_len++;
}

FAKE_EXPORT void fake_k4abt_fail_next_creates(int n) { g_fail_creates = n; }

/* Lets every pop hung by FAKE_K4ABT_FAULT=hang return (TIMEOUT); for tests that hang a call in-process. */
FAKE_EXPORT void fake_k4abt_release_hangs(void) { g_release_hangs = 1; }

/* Echo mode: with an empty script, every capture yields one body computed from the capture's depth image and
 * the calibration the tracker was created with, so that the test can recompute it independently:
 *   joint 0 position: the mean of the valid depth pixels lifted with the calibration's depth intrinsics
 *                     (x = (u - cx) d / fx, y = (v - cy) d / fy, z = d), rows read with the image's stride;
 *   joint 1 position: (valid pixel count, mean IR over them (0 without IR), depth stride in bytes);
 *   joint 2 position: (depth_mode, depth resolution_width, resolution_height);
 *   joint 3 position: (intrinsics type, parameter_count, metric_radius).
 * The body frame's device timestamp is the depth image's. A capture without a DEPTH16 image of the
 * calibration's resolution is refused (enqueue FAILED, counted as a bad capture). */
FAKE_EXPORT void fake_k4abt_set_echo(int on) { g_echo = on; }

static fake_frame *echo_frame(const fake_tracker *tracker, const fake_capture *capture) {
    const fake_image *depth = capture->depth;
    const k4a_calibration_camera_t *camera = &tracker->calibration.depth_camera_calibration;
    if (depth == NULL || depth->magic != FAKE_IMAGE_MAGIC || depth->format != K4A_IMAGE_FORMAT_DEPTH16 ||
        depth->width != camera->resolution_width || depth->height != camera->resolution_height)
        return NULL;
    const fake_image *ir = capture->ir;
    if (ir != NULL && (ir->magic != FAKE_IMAGE_MAGIC || ir->format != K4A_IMAGE_FORMAT_IR16 ||
                       ir->width != depth->width || ir->height != depth->height))
        return NULL;
    const float cx = camera->intrinsics.parameters.param.cx, cy = camera->intrinsics.parameters.param.cy;
    const float fx = camera->intrinsics.parameters.param.fx, fy = camera->intrinsics.parameters.param.fy;
    double sum[3] = {0, 0, 0}, ir_sum = 0;
    long count = 0;
    for (int v = 0; v < depth->height; v++) {
        const uint16_t *row = (const uint16_t *)(depth->buffer + (size_t)v * (size_t)depth->stride);
        const uint16_t *ir_row = ir ? (const uint16_t *)(ir->buffer + (size_t)v * (size_t)ir->stride) : NULL;
        for (int u = 0; u < depth->width; u++) {
            double d = row[u];
            if (d <= 0) continue;
            sum[0] += (u - cx) * d / fx;
            sum[1] += (v - cy) * d / fy;
            sum[2] += d;
            if (ir_row) ir_sum += ir_row[u];
            count++;
        }
    }
    k4abt_skeleton_t skeleton;
    memset(&skeleton, 0, sizeof(skeleton));
    for (int j = 0; j < K4ABT_JOINT_COUNT; j++) {
        skeleton.joints[j].orientation.wxyz.w = 1.0f;
        skeleton.joints[j].confidence_level = K4ABT_JOINT_CONFIDENCE_MEDIUM;
    }
    if (count > 0)
        for (int a = 0; a < 3; a++) skeleton.joints[0].position.v[a] = (float)(sum[a] / (double)count);
    skeleton.joints[1].position.v[0] = (float)count;
    skeleton.joints[1].position.v[1] = count > 0 ? (float)(ir_sum / (double)count) : 0.0f;
    skeleton.joints[1].position.v[2] = (float)depth->stride;
    skeleton.joints[2].position.v[0] = (float)tracker->calibration.depth_mode;
    skeleton.joints[2].position.v[1] = (float)camera->resolution_width;
    skeleton.joints[2].position.v[2] = (float)camera->resolution_height;
    skeleton.joints[3].position.v[0] = (float)camera->intrinsics.type;
    skeleton.joints[3].position.v[1] = (float)camera->intrinsics.parameter_count;
    skeleton.joints[3].position.v[2] = camera->metric_radius;
    uint32_t id = 1;
    return new_frame(depth->device_usec, 0, count > 0 ? 1 : 0, &id, &skeleton);
}

FAKE_EXPORT void fake_k4abt_get_stats(fake_stats *out) {
    g_stats.abi = FAKE_K4ABT_ABI;
    *out = g_stats;
}

FAKE_EXPORT int fake_k4abt_abi(void) { return FAKE_K4ABT_ABI; }

FAKE_EXPORT size_t fake_k4abt_layout(const char *name) {
#define L(key, value) if (strcmp(name, key) == 0) return (value)
    L("float3", sizeof(k4a_float3_t));
    L("quaternion", sizeof(k4a_quaternion_t));
    L("joint", sizeof(k4abt_joint_t));
    L("joint.position", offsetof(k4abt_joint_t, position));
    L("joint.orientation", offsetof(k4abt_joint_t, orientation));
    L("joint.confidence_level", offsetof(k4abt_joint_t, confidence_level));
    L("skeleton", sizeof(k4abt_skeleton_t));
    L("config", sizeof(k4abt_tracker_configuration_t));
    L("config.sensor_orientation", offsetof(k4abt_tracker_configuration_t, sensor_orientation));
    L("config.gpu_device_id", offsetof(k4abt_tracker_configuration_t, gpu_device_id));
#if FAKE_K4ABT_ABI >= 11
    L("config.processing_mode", offsetof(k4abt_tracker_configuration_t, processing_mode));
    L("config.model_path", offsetof(k4abt_tracker_configuration_t, model_path));
#else
    L("config.cpu_only_mode", offsetof(k4abt_tracker_configuration_t, cpu_only_mode));
#endif
#undef L
    return (size_t)-1;
}

/* ------------------------------------------------------------------ k4abt.h */

FAKE_EXPORT k4a_result_t k4abt_tracker_create(const k4a_calibration_t *sensor_calibration,
                                              k4abt_tracker_configuration_t config, k4abt_tracker_t *tracker_handle) {
    g_stats.last_calibration = sensor_calibration;
    g_stats.config_sensor_orientation = (int32_t)config.sensor_orientation;
    g_stats.config_gpu_device_id = config.gpu_device_id;
#if FAKE_K4ABT_ABI >= 11
    g_stats.config_processing_mode = (int32_t)config.processing_mode;
    g_stats.model_path[0] = '\0';
    if (config.model_path != NULL) {
        strncpy(g_stats.model_path, config.model_path, sizeof(g_stats.model_path) - 1);
        g_stats.model_path[sizeof(g_stats.model_path) - 1] = '\0';
    }
#else
    g_stats.config_processing_mode = config.cpu_only_mode ? 1 : 0;
#endif
    if (sensor_calibration == NULL || tracker_handle == NULL) return K4A_RESULT_FAILED;
    const char *one = getenv("FAKE_K4ABT_ONE_TRACKER");
    if (one != NULL && strcmp(one, "1") == 0 && g_trackers_alive > 0) return K4A_RESULT_FAILED;
    const char *echo = getenv("FAKE_K4ABT_ECHO");
    if (echo != NULL && strcmp(echo, "1") == 0) g_echo = 1;
    if (g_fail_creates > 0) {
        g_fail_creates--;
        return K4A_RESULT_FAILED;
    }
    fake_tracker *tracker = calloc(1, sizeof(fake_tracker));
    tracker->magic = 0x4B344254u;
    tracker->calibration = *sensor_calibration;
    tracker->index = g_trackers_made++;
    g_trackers_alive++;
    *tracker_handle = (k4abt_tracker_t)tracker;
    g_stats.created++;
    return K4A_RESULT_SUCCEEDED;
}

FAKE_EXPORT void k4abt_tracker_destroy(k4abt_tracker_t tracker_handle) {
    fake_tracker *tracker = (fake_tracker *)tracker_handle;
    if (tracker == NULL) return;
    tracker->magic = 0;
    free(tracker);
    g_trackers_alive--;
    g_stats.destroyed++;
}

FAKE_EXPORT void k4abt_tracker_set_temporal_smoothing(k4abt_tracker_t tracker_handle, float smoothing_factor) {
    (void)tracker_handle;
    g_stats.smoothing = smoothing_factor;
    g_stats.smoothing_calls++;
}

FAKE_EXPORT k4a_wait_result_t k4abt_tracker_enqueue_capture(k4abt_tracker_t tracker_handle,
                                                            k4a_capture_t sensor_capture_handle, int32_t timeout_in_ms) {
    fake_tracker *tracker = (fake_tracker *)tracker_handle;
    if (timeout_in_ms < 0) {
        g_stats.infinite_waits++;
        return K4A_WAIT_RESULT_FAILED;
    }
    if (tracker == NULL || tracker->magic != 0x4B344254u || tracker->shutdown) return K4A_WAIT_RESULT_FAILED;
    g_stats.last_capture = sensor_capture_handle;
    if (sensor_capture_handle == NULL || sensor_capture_handle->_rsvd != FAKE_CAPTURE_MAGIC) {
        g_stats.bad_captures++;
        return K4A_WAIT_RESULT_FAILED;
    }
    if (g_ready_len >= FAKE_QUEUE_MAX) {
        nap_ms(timeout_in_ms);
        return K4A_WAIT_RESULT_TIMEOUT;
    }
    fake_event event = {EV_FRAME, NULL};
    if (g_script_head < g_script_len) event = g_script[g_script_head++];
    switch (event.kind) {
    case EV_ENQUEUE_TIMEOUT:
        nap_ms(timeout_in_ms);
        return K4A_WAIT_RESULT_TIMEOUT;
    case EV_ENQUEUE_FAILED:
        return K4A_WAIT_RESULT_FAILED;
    case EV_DROP:
        g_stats.enqueued++;
        return K4A_WAIT_RESULT_SUCCEEDED;
    case EV_POP_FAILED: {
        fake_frame *marker = new_frame(0, 0, 0, NULL, NULL);
        marker->failed = 1;
        g_ready[g_ready_len++] = marker;
        g_stats.enqueued++;
        return K4A_WAIT_RESULT_SUCCEEDED;
    }
    default:
        if (event.frame == NULL && g_echo) {
            event.frame = echo_frame(tracker, (const fake_capture *)sensor_capture_handle);
            if (event.frame == NULL) {
                g_stats.bad_captures++;
                return K4A_WAIT_RESULT_FAILED;
            }
        }
        if (event.frame == NULL) {
            g_auto_time += 33333;
            event.frame = new_frame(g_auto_time, g_auto_time * 1000, 0, NULL, NULL);
        }
        event.frame->capture = (fake_capture *)sensor_capture_handle; /* k4abt_frame_get_capture gives it back */
        event.frame->capture->refcount++;
        g_ready[g_ready_len++] = event.frame;
        g_stats.enqueued++;
        return K4A_WAIT_RESULT_SUCCEEDED;
    }
}

FAKE_EXPORT k4a_wait_result_t k4abt_tracker_pop_result(k4abt_tracker_t tracker_handle, k4abt_frame_t *body_frame_handle,
                                                       int32_t timeout_in_ms) {
    fake_tracker *tracker = (fake_tracker *)tracker_handle;
    if (timeout_in_ms < 0) {
        g_stats.infinite_waits++;
        return K4A_WAIT_RESULT_FAILED;
    }
    if (tracker == NULL || tracker->magic != 0x4B344254u || body_frame_handle == NULL) return K4A_WAIT_RESULT_FAILED;
    switch (fault_now(tracker)) {
    case FAULT_HANG:
        if (!tracker->hang_said) {
            tracker->hang_said = 1;
            fprintf(stderr, "fake_k4abt: tracker %d hangs in k4abt_tracker_pop_result after %d results\n",
                    tracker->index, tracker->delivered);
            fflush(stderr);
        }
        while (!g_release_hangs) nap_ms(20);
        return K4A_WAIT_RESULT_TIMEOUT;
    case FAULT_STALL:
        nap_ms(timeout_in_ms);
        return K4A_WAIT_RESULT_TIMEOUT;
    default:
        break;
    }
    if (g_ready_len == 0) {
        if (tracker->shutdown) return K4A_WAIT_RESULT_FAILED;
        nap_ms(timeout_in_ms);
        return K4A_WAIT_RESULT_TIMEOUT;
    }
    fake_frame *frame = g_ready[0];
    memmove(g_ready, g_ready + 1, (size_t)(g_ready_len - 1) * sizeof(fake_frame *));
    g_ready_len--;
    if (frame->failed) {
        free_frame(frame);
        return K4A_WAIT_RESULT_FAILED;
    }
    frame->refcount = 1;
    tracker->delivered++;
    g_stats.frames_alive++;
    g_stats.popped++;
    *body_frame_handle = (k4abt_frame_t)frame;
    return K4A_WAIT_RESULT_SUCCEEDED;
}

FAKE_EXPORT void k4abt_tracker_shutdown(k4abt_tracker_t tracker_handle) {
    fake_tracker *tracker = (fake_tracker *)tracker_handle;
    if (tracker == NULL) return;
    tracker->shutdown = 1;
    g_stats.shutdowns++;
}

static fake_frame *as_frame(k4abt_frame_t handle) {
    fake_frame *frame = (fake_frame *)handle;
    return (frame != NULL && frame->magic == FAKE_FRAME_MAGIC) ? frame : NULL;
}

FAKE_EXPORT void k4abt_frame_release(k4abt_frame_t handle) {
    fake_frame *frame = as_frame(handle);
    if (frame != NULL && --frame->refcount == 0) {
        free_frame(frame);
        g_stats.frames_alive--;
    }
}

FAKE_EXPORT void k4abt_frame_reference(k4abt_frame_t handle) {
    fake_frame *frame = as_frame(handle);
    if (frame != NULL) frame->refcount++;
}

FAKE_EXPORT uint32_t k4abt_frame_get_num_bodies(k4abt_frame_t handle) {
    fake_frame *frame = as_frame(handle);
    return frame ? frame->n_bodies : 0;
}

FAKE_EXPORT k4a_result_t k4abt_frame_get_body_skeleton(k4abt_frame_t handle, uint32_t index, k4abt_skeleton_t *skeleton) {
    fake_frame *frame = as_frame(handle);
    if (frame == NULL || skeleton == NULL || index >= frame->n_bodies) return K4A_RESULT_FAILED;
    *skeleton = frame->skeletons[index];
    return K4A_RESULT_SUCCEEDED;
}

FAKE_EXPORT uint32_t k4abt_frame_get_body_id(k4abt_frame_t handle, uint32_t index) {
    fake_frame *frame = as_frame(handle);
    if (frame == NULL || index >= frame->n_bodies) return 0xFFFFFFFFu; /* K4ABT_INVALID_BODY_ID */
    return frame->ids[index];
}

#if FAKE_K4ABT_ABI >= 11
FAKE_EXPORT uint64_t k4abt_frame_get_device_timestamp_usec(k4abt_frame_t handle) {
    fake_frame *frame = as_frame(handle);
    return frame ? frame->device_usec : 0;
}

FAKE_EXPORT uint64_t k4abt_frame_get_system_timestamp_nsec(k4abt_frame_t handle) {
    fake_frame *frame = as_frame(handle);
    return frame ? frame->system_nsec : 0;
}
#else
FAKE_EXPORT uint64_t k4abt_frame_get_timestamp_usec(k4abt_frame_t handle) {
    fake_frame *frame = as_frame(handle);
    return frame ? frame->device_usec : 0;
}
#endif

/* The body-index map of a frame: a CUSTOM8 image of the capture's depth size, 255 (background) where the depth
 * is 0 or the frame has no body; elsewhere the body index of the pixel's column strip, u * n_bodies / width
 * (body 0 on the left), so that a test can recompute it. Made through the fake libk4a (the caller releases it
 * with k4a_image_release); NULL for a frame without a capture or depth image. */
static void free_map_buffer(void *buffer, void *context) {
    (void)context;
    free(buffer);
}

FAKE_EXPORT k4a_image_t k4abt_frame_get_body_index_map(k4abt_frame_t handle) {
    fake_frame *frame = as_frame(handle);
    if (frame == NULL || frame->capture == NULL || frame->capture->depth == NULL) return NULL;
    const fake_image *depth = frame->capture->depth;
    const int width = depth->width, height = depth->height;
    uint8_t *map = malloc((size_t)width * (size_t)height);
    for (int v = 0; v < height; v++) {
        const uint16_t *row = (const uint16_t *)(depth->buffer + (size_t)v * (size_t)depth->stride);
        for (int u = 0; u < width; u++)
            map[(size_t)v * (size_t)width + (size_t)u] =
                (row[u] > 0 && frame->n_bodies > 0) ? (uint8_t)(((long)u * (long)frame->n_bodies) / width) : 255;
    }
    k4a_image_t image = NULL;
    if (frame->capture->create_image(K4A_IMAGE_FORMAT_CUSTOM8, width, height, width, map,
                                     (size_t)width * (size_t)height, free_map_buffer, NULL, &image) != K4A_RESULT_SUCCEEDED) {
        free(map);
        return NULL;
    }
    return image;
}

FAKE_EXPORT k4a_capture_t k4abt_frame_get_capture(k4abt_frame_t handle) {
    fake_frame *frame = as_frame(handle);
    if (frame == NULL || frame->capture == NULL) return NULL;
    frame->capture->refcount++; /* the caller releases it with k4a_capture_release */
    return (k4a_capture_t)frame->capture;
}
