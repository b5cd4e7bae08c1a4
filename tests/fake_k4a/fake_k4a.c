/* Fake libk4a: just what skelfuse touches (device listing, capture handles). Devices come from the
 * environment variable FAKE_K4A_DEVICES, read at each call: "SERIAL[:IN:OUT];SERIAL2[:IN:OUT]" where IN
 * and OUT are 0/1 (sync jack connected). Firmware versions are derived from the device index.
 *
 * k4a_calibration_2d_to_3d unprojects with the Sensor SDK's lens model (see the comment at the function). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "k4a_abi.h"

#define MAX_DEVICES 16

typedef struct { char serial[64]; bool sync_in; bool sync_out; } fake_device_info;
typedef struct { size_t magic; uint32_t index; int open; } fake_device;

static int g_captures_alive = 0;
static int g_images_alive = 0;

static int read_devices(fake_device_info *out) {
    const char *env = getenv("FAKE_K4A_DEVICES");
    if (env == NULL || env[0] == '\0') return 0;
    char buffer[1024];
    strncpy(buffer, env, sizeof(buffer) - 1);
    buffer[sizeof(buffer) - 1] = '\0';
    int n = 0;
    char *save = NULL;
    for (char *item = strtok_r(buffer, ";", &save); item != NULL && n < MAX_DEVICES; item = strtok_r(NULL, ";", &save)) {
        int in = 0, out_jack = 0;
        char *colon = strchr(item, ':');
        if (colon != NULL) {
            *colon = '\0';
            sscanf(colon + 1, "%d:%d", &in, &out_jack);
        }
        strncpy(out[n].serial, item, sizeof(out[n].serial) - 1);
        out[n].serial[sizeof(out[n].serial) - 1] = '\0';
        out[n].sync_in = in != 0;
        out[n].sync_out = out_jack != 0;
        n++;
    }
    return n;
}

FAKE_EXPORT uint32_t k4a_device_get_installed_count(void) {
    fake_device_info devices[MAX_DEVICES];
    return (uint32_t)read_devices(devices);
}

FAKE_EXPORT k4a_result_t k4a_device_open(uint32_t index, k4a_device_t *device_handle) {
    fake_device_info devices[MAX_DEVICES];
    if (device_handle == NULL || index >= (uint32_t)read_devices(devices)) return K4A_RESULT_FAILED;
    fake_device *device = calloc(1, sizeof(fake_device));
    device->magic = 0x4B344144u;
    device->index = index;
    device->open = 1;
    *device_handle = (k4a_device_t)device;
    return K4A_RESULT_SUCCEEDED;
}

FAKE_EXPORT void k4a_device_close(k4a_device_t device_handle) { free(device_handle); }

static fake_device_info *lookup(k4a_device_t handle, fake_device_info *devices) {
    fake_device *device = (fake_device *)handle;
    if (device == NULL || device->magic != 0x4B344144u) return NULL;
    int n = read_devices(devices);
    return device->index < (uint32_t)n ? &devices[device->index] : NULL;
}

FAKE_EXPORT k4a_buffer_result_t k4a_device_get_serialnum(k4a_device_t handle, char *serial, size_t *size) {
    fake_device_info devices[MAX_DEVICES];
    fake_device_info *info = lookup(handle, devices);
    if (info == NULL || size == NULL) return K4A_BUFFER_RESULT_FAILED;
    size_t needed = strlen(info->serial) + 1;
    if (serial == NULL || *size < needed) {
        *size = needed;
        return K4A_BUFFER_RESULT_TOO_SMALL;
    }
    memcpy(serial, info->serial, needed);
    *size = needed;
    return K4A_BUFFER_RESULT_SUCCEEDED;
}

FAKE_EXPORT k4a_result_t k4a_device_get_version(k4a_device_t handle, k4a_hardware_version_t *version) {
    fake_device_info devices[MAX_DEVICES];
    fake_device *device = (fake_device *)handle;
    if (lookup(handle, devices) == NULL || version == NULL) return K4A_RESULT_FAILED;
    uint32_t i = device->index;
    version->rgb = (k4a_version_t){1, 6, 110 + i};
    version->depth = (k4a_version_t){1, 6, 79 + i};
    version->audio = (k4a_version_t){1, 6, 14 + i};
    version->depth_sensor = (k4a_version_t){6109, 7, 0};
    version->firmware_build = K4A_FIRMWARE_BUILD_RELEASE;
    version->firmware_signature = K4A_FIRMWARE_SIGNATURE_MSFT;
    return K4A_RESULT_SUCCEEDED;
}

FAKE_EXPORT k4a_result_t k4a_device_get_sync_jack(k4a_device_t handle, bool *in, bool *out) {
    fake_device_info devices[MAX_DEVICES];
    fake_device_info *info = lookup(handle, devices);
    if (info == NULL || in == NULL || out == NULL) return K4A_RESULT_FAILED;
    *in = info->sync_in;
    *out = info->sync_out;
    return K4A_RESULT_SUCCEEDED;
}

FAKE_EXPORT void k4a_capture_release(k4a_capture_t handle);
FAKE_EXPORT k4a_result_t k4a_image_create_from_buffer(k4a_image_format_t format, int width_pixels, int height_pixels,
                                                      int stride_bytes, uint8_t *buffer, size_t buffer_size,
                                                      k4a_memory_destroy_cb_t *buffer_release_cb,
                                                      void *buffer_release_cb_context, k4a_image_t *image_handle);

FAKE_EXPORT k4a_result_t k4a_capture_create(k4a_capture_t *capture_handle) {
    if (capture_handle == NULL) return K4A_RESULT_FAILED;
    fake_capture *capture = calloc(1, sizeof(fake_capture));
    capture->magic = FAKE_CAPTURE_MAGIC;
    capture->refcount = 1;
    capture->release = k4a_capture_release;
    capture->create_image = k4a_image_create_from_buffer;
    g_captures_alive++;
    *capture_handle = (k4a_capture_t)capture;
    return K4A_RESULT_SUCCEEDED;
}

FAKE_EXPORT void k4a_capture_reference(k4a_capture_t handle) { ((fake_capture *)handle)->refcount++; }

/* ---- images (k4a_image_create_from_buffer and what a capture does with them) ---- */

static fake_image *as_image(k4a_image_t handle) {
    fake_image *image = (fake_image *)handle;
    return (image != NULL && image->magic == FAKE_IMAGE_MAGIC) ? image : NULL;
}

FAKE_EXPORT k4a_result_t k4a_image_create_from_buffer(k4a_image_format_t format, int width_pixels, int height_pixels,
                                                      int stride_bytes, uint8_t *buffer, size_t buffer_size,
                                                      k4a_memory_destroy_cb_t *buffer_release_cb,
                                                      void *buffer_release_cb_context, k4a_image_t *image_handle) {
    int bytes_per_pixel = (format == K4A_IMAGE_FORMAT_DEPTH16 || format == K4A_IMAGE_FORMAT_IR16 ||
                           format == K4A_IMAGE_FORMAT_CUSTOM16) ? 2 : 1;
    if (image_handle == NULL || buffer == NULL || width_pixels <= 0 || height_pixels <= 0 ||
        stride_bytes < width_pixels * bytes_per_pixel || buffer_size < (size_t)stride_bytes * (size_t)height_pixels)
        return K4A_RESULT_FAILED;
    fake_image *image = calloc(1, sizeof(fake_image));
    image->magic = FAKE_IMAGE_MAGIC;
    image->refcount = 1;
    image->format = format;
    image->width = width_pixels;
    image->height = height_pixels;
    image->stride = stride_bytes;
    image->buffer = buffer;
    image->size = buffer_size;
    image->release = buffer_release_cb;
    image->context = buffer_release_cb_context;
    g_images_alive++;
    *image_handle = (k4a_image_t)image;
    return K4A_RESULT_SUCCEEDED;
}

FAKE_EXPORT void k4a_image_reference(k4a_image_t handle) {
    fake_image *image = as_image(handle);
    if (image != NULL) image->refcount++;
}

FAKE_EXPORT void k4a_image_release(k4a_image_t handle) {
    fake_image *image = as_image(handle);
    if (image != NULL && --image->refcount == 0) {
        if (image->release != NULL) image->release(image->buffer, image->context);
        image->magic = 0;
        free(image);
        g_images_alive--;
    }
}

FAKE_EXPORT void k4a_image_set_device_timestamp_usec(k4a_image_t handle, uint64_t timestamp_usec) {
    fake_image *image = as_image(handle);
    if (image != NULL) image->device_usec = timestamp_usec;
}

static void set_image(fake_image **slot, k4a_image_t handle) {
    fake_image *image = as_image(handle);
    if (image != NULL) image->refcount++;
    if (*slot != NULL) k4a_image_release((k4a_image_t)*slot);
    *slot = image;
}

FAKE_EXPORT void k4a_capture_set_depth_image(k4a_capture_t capture_handle, k4a_image_t image_handle) {
    fake_capture *capture = (fake_capture *)capture_handle;
    if (capture != NULL && capture->magic == FAKE_CAPTURE_MAGIC) set_image(&capture->depth, image_handle);
}

FAKE_EXPORT void k4a_capture_set_ir_image(k4a_capture_t capture_handle, k4a_image_t image_handle) {
    fake_capture *capture = (fake_capture *)capture_handle;
    if (capture != NULL && capture->magic == FAKE_CAPTURE_MAGIC) set_image(&capture->ir, image_handle);
}

FAKE_EXPORT void k4a_capture_release(k4a_capture_t handle) {
    fake_capture *capture = (fake_capture *)handle;
    if (capture != NULL && --capture->refcount == 0) {
        if (capture->depth != NULL) k4a_image_release((k4a_image_t)capture->depth);
        if (capture->ir != NULL) k4a_image_release((k4a_image_t)capture->ir);
        capture->magic = 0;
        free(capture);
        g_captures_alive--;
    }
}

/* ---- reading images back (k4a_capture_get_depth_image, k4a_image_get_*) ---- */

FAKE_EXPORT k4a_image_t k4a_capture_get_depth_image(k4a_capture_t capture_handle) {
    fake_capture *capture = (fake_capture *)capture_handle;
    if (capture == NULL || capture->magic != FAKE_CAPTURE_MAGIC || capture->depth == NULL) return NULL;
    capture->depth->refcount++; /* the caller releases it */
    return (k4a_image_t)capture->depth;
}

FAKE_EXPORT uint8_t *k4a_image_get_buffer(k4a_image_t handle) {
    fake_image *image = as_image(handle);
    return image != NULL ? image->buffer : NULL;
}
FAKE_EXPORT size_t k4a_image_get_size(k4a_image_t handle) {
    fake_image *image = as_image(handle);
    return image != NULL ? image->size : 0;
}
FAKE_EXPORT k4a_image_format_t k4a_image_get_format(k4a_image_t handle) {
    fake_image *image = as_image(handle);
    return image != NULL ? image->format : K4A_IMAGE_FORMAT_CUSTOM;
}
FAKE_EXPORT int k4a_image_get_width_pixels(k4a_image_t handle) {
    fake_image *image = as_image(handle);
    return image != NULL ? image->width : 0;
}
FAKE_EXPORT int k4a_image_get_height_pixels(k4a_image_t handle) {
    fake_image *image = as_image(handle);
    return image != NULL ? image->height : 0;
}
FAKE_EXPORT int k4a_image_get_stride_bytes(k4a_image_t handle) {
    fake_image *image = as_image(handle);
    return image != NULL ? image->stride : 0;
}
FAKE_EXPORT uint64_t k4a_image_get_device_timestamp_usec(k4a_image_t handle) {
    fake_image *image = as_image(handle);
    return image != NULL ? image->device_usec : 0;
}

/* ---- k4a_calibration_2d_to_3d: the SDK's Brown-Conrady lens model ----
 * Our own transcription of the model the Sensor SDK 1.4 documents and implements in
 * src/transformation/intrinsic_transformation.c (not its code): a normalized ray (x, y) = (X/Z, Y/Z) maps to
 * the pixel
 *     r2 = x^2 + y^2   (the ray is invalid beyond the camera's metric_radius: r2 > metric_radius^2)
 *     d  = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3)
 *     xd = x d + (r2 + 2 x^2) p2 + 2 x y p1        (RATIONAL_6KT: x y p1, without the 2)
 *     yd = y d + (r2 + 2 y^2) p1 + 2 x y p2        (RATIONAL_6KT: x y p2)
 *     u  = (xd + codx) fx + cx,   v = (yd + cody) fy + cy    (x, y taken relative to (codx, cody) first)
 * and the unprojection inverts it by Gauss-Newton from the pinhole guess, at most 20 passes, keeping the best
 * pass; a pixel whose best reprojection error stays above 1e-3 px (1e-6 px^2, the SDK's bound), or a pass
 * that leaves the metric radius, makes the pixel invalid. Computed in double here (the SDK uses float).
 * Pixel (0, 0) is the centre of the top-left pixel. Depth 0: point (0, 0, 0), invalid. Only source camera ==
 * target camera is supported (no extrinsics in the fake); the SDK applies the extrinsics otherwise. */

static int g_unprojections = 0;

/* The pixel of the normalized ray (x, y), with d(u, v)/d(x, y) in J (row-major); 0 beyond the metric radius. */
static int lens_project(const k4a_calibration_camera_t *camera, double x, double y, double uv[2], double J[4]) {
    const struct _param *q = &camera->intrinsics.parameters.param;
    const int six_kt = camera->intrinsics.type == K4A_CALIBRATION_LENS_DISTORTION_MODEL_RATIONAL_6KT;
    const double t = six_kt ? 1.0 : 2.0; /* the factor of the x y p terms */
    const double xp = x - q->codx, yp = y - q->cody;
    const double r2 = xp * xp + yp * yp;
    const double radius = camera->metric_radius;
    if (r2 > radius * radius) return 0;
    const double num = 1.0 + r2 * (q->k1 + r2 * (q->k2 + r2 * q->k3));
    const double den = 1.0 + r2 * (q->k4 + r2 * (q->k5 + r2 * q->k6));
    const double dnum = q->k1 + r2 * (2.0 * q->k2 + 3.0 * q->k3 * r2); /* d num / d r2 */
    const double dden = q->k4 + r2 * (2.0 * q->k5 + 3.0 * q->k6 * r2);
    const double d = den != 0.0 ? num / den : num;
    const double dd = den != 0.0 ? (dnum * den - num * dden) / (den * den) : dnum; /* d d / d r2 */
    const double xd = xp * d + (r2 + 2.0 * xp * xp) * q->p2 + t * xp * yp * q->p1;
    const double yd = yp * d + (r2 + 2.0 * yp * yp) * q->p1 + t * xp * yp * q->p2;
    uv[0] = (xd + q->codx) * q->fx + q->cx;
    uv[1] = (yd + q->cody) * q->fy + q->cy;
    /* d r2 / d xp = 2 xp, d r2 / d yp = 2 yp */
    J[0] = q->fx * (d + xp * dd * 2.0 * xp + 6.0 * xp * q->p2 + t * yp * q->p1);
    J[1] = q->fx * (xp * dd * 2.0 * yp + 2.0 * yp * q->p2 + t * xp * q->p1);
    J[2] = q->fy * (yp * dd * 2.0 * xp + 2.0 * xp * q->p1 + t * yp * q->p2);
    J[3] = q->fy * (d + yp * dd * 2.0 * yp + 6.0 * yp * q->p1 + t * xp * q->p2);
    return 1;
}

static int lens_unproject(const k4a_calibration_camera_t *camera, double u, double v, double xy[2]) {
    const struct _param *q = &camera->intrinsics.parameters.param;
    double x = (u - q->cx) / q->fx, y = (v - q->cy) / q->fy; /* the pinhole guess */
    double best[2] = {x, y}, best_error = INFINITY;
    for (int pass = 0; pass < 20; pass++) {
        double uv[2], J[4];
        if (!lens_project(camera, x, y, uv, J)) return 0; /* a pass beyond the metric radius: invalid */
        const double eu = u - uv[0], ev = v - uv[1], error = eu * eu + ev * ev;
        if (error >= best_error) break;
        best_error = error;
        best[0] = x;
        best[1] = y;
        if (error < 1e-22) break;
        const double det = J[0] * J[3] - J[1] * J[2];
        if (det == 0.0) break;
        x += (J[3] * eu - J[1] * ev) / det;
        y += (-J[2] * eu + J[0] * ev) / det;
    }
    xy[0] = best[0];
    xy[1] = best[1];
    return best_error <= 1e-6;
}

FAKE_EXPORT k4a_result_t k4a_calibration_2d_to_3d(const k4a_calibration_t *calibration, const k4a_float2_t *source_point2d,
                                                  const float source_depth_mm, const k4a_calibration_type_t source_camera,
                                                  const k4a_calibration_type_t target_camera,
                                                  k4a_float3_t *target_point3d_mm, int *valid) {
    if (calibration == NULL || source_point2d == NULL || target_point3d_mm == NULL || valid == NULL) return K4A_RESULT_FAILED;
    if (source_camera != target_camera ||
        (source_camera != K4A_CALIBRATION_TYPE_DEPTH && source_camera != K4A_CALIBRATION_TYPE_COLOR))
        return K4A_RESULT_FAILED;
    const k4a_calibration_camera_t *camera = source_camera == K4A_CALIBRATION_TYPE_DEPTH
                                                 ? &calibration->depth_camera_calibration
                                                 : &calibration->color_camera_calibration;
    const k4a_calibration_model_type_t type = camera->intrinsics.type;
    if ((type != K4A_CALIBRATION_LENS_DISTORTION_MODEL_BROWN_CONRADY &&
         type != K4A_CALIBRATION_LENS_DISTORTION_MODEL_RATIONAL_6KT) ||
        camera->intrinsics.parameter_count < 14 || !(camera->intrinsics.parameters.param.fx > 0.f) ||
        !(camera->intrinsics.parameters.param.fy > 0.f))
        return K4A_RESULT_FAILED;
    g_unprojections++;
    target_point3d_mm->xyz.x = target_point3d_mm->xyz.y = target_point3d_mm->xyz.z = 0.f;
    *valid = 0;
    if (source_depth_mm == 0.f) return K4A_RESULT_SUCCEEDED;
    double xy[2] = {0.0, 0.0};
    *valid = lens_unproject(camera, source_point2d->xy.x, source_point2d->xy.y, xy);
    target_point3d_mm->xyz.x = (float)(xy[0] * source_depth_mm);
    target_point3d_mm->xyz.y = (float)(xy[1] * source_depth_mm);
    target_point3d_mm->xyz.z = source_depth_mm;
    return K4A_RESULT_SUCCEEDED;
}

/* ---- test control ---- */
FAKE_EXPORT int fake_k4a_unprojections(void) { return g_unprojections; }
FAKE_EXPORT int fake_k4a_captures_alive(void) { return g_captures_alive; }
FAKE_EXPORT int fake_k4a_images_alive(void) { return g_images_alive; }

FAKE_EXPORT size_t fake_k4a_layout(const char *name) {
    if (strcmp(name, "version") == 0) return sizeof(k4a_version_t);
    if (strcmp(name, "hardware_version") == 0) return sizeof(k4a_hardware_version_t);
    if (strcmp(name, "hardware_version.depth") == 0) return offsetof(k4a_hardware_version_t, depth);
    if (strcmp(name, "hardware_version.depth_sensor") == 0) return offsetof(k4a_hardware_version_t, depth_sensor);
    if (strcmp(name, "hardware_version.firmware_build") == 0) return offsetof(k4a_hardware_version_t, firmware_build);
    if (strcmp(name, "hardware_version.firmware_signature") == 0) return offsetof(k4a_hardware_version_t, firmware_signature);
#define L(key, value) if (strcmp(name, key) == 0) return (value)
    L("calibration", sizeof(k4a_calibration_t));
    L("calibration.color_camera_calibration", offsetof(k4a_calibration_t, color_camera_calibration));
    L("calibration.extrinsics", offsetof(k4a_calibration_t, extrinsics));
    L("calibration.depth_mode", offsetof(k4a_calibration_t, depth_mode));
    L("calibration.color_resolution", offsetof(k4a_calibration_t, color_resolution));
    L("calibration_camera", sizeof(k4a_calibration_camera_t));
    L("calibration_camera.intrinsics", offsetof(k4a_calibration_camera_t, intrinsics));
    L("calibration_camera.resolution_width", offsetof(k4a_calibration_camera_t, resolution_width));
    L("calibration_camera.resolution_height", offsetof(k4a_calibration_camera_t, resolution_height));
    L("calibration_camera.metric_radius", offsetof(k4a_calibration_camera_t, metric_radius));
    L("intrinsics", sizeof(k4a_calibration_intrinsics_t));
    L("intrinsics.parameter_count", offsetof(k4a_calibration_intrinsics_t, parameter_count));
    L("intrinsics.parameters", offsetof(k4a_calibration_intrinsics_t, parameters));
    L("extrinsics", sizeof(k4a_calibration_extrinsics_t));
    L("float2", sizeof(k4a_float2_t));
#undef L
    return (size_t)-1;
}
