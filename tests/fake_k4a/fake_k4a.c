/* Fake libk4a: just what skelfuse touches (device listing, capture handles). Devices come from the
 * environment variable FAKE_K4A_DEVICES, read at each call: "SERIAL[:IN:OUT];SERIAL2[:IN:OUT]" where IN
 * and OUT are 0/1 (sync jack connected). Firmware versions are derived from the device index. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "k4a_abi.h"

#define MAX_DEVICES 16

typedef struct { char serial[64]; bool sync_in; bool sync_out; } fake_device_info;
typedef struct { size_t magic; uint32_t index; int open; } fake_device;
typedef struct { size_t magic; int refcount; } fake_capture;

static int g_captures_alive = 0;

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

FAKE_EXPORT k4a_result_t k4a_capture_create(k4a_capture_t *capture_handle) {
    if (capture_handle == NULL) return K4A_RESULT_FAILED;
    fake_capture *capture = calloc(1, sizeof(fake_capture));
    capture->magic = FAKE_CAPTURE_MAGIC;
    capture->refcount = 1;
    g_captures_alive++;
    *capture_handle = (k4a_capture_t)capture;
    return K4A_RESULT_SUCCEEDED;
}

FAKE_EXPORT void k4a_capture_reference(k4a_capture_t handle) { ((fake_capture *)handle)->refcount++; }

FAKE_EXPORT void k4a_capture_release(k4a_capture_t handle) {
    fake_capture *capture = (fake_capture *)handle;
    if (capture != NULL && --capture->refcount == 0) {
        capture->magic = 0;
        free(capture);
        g_captures_alive--;
    }
}

/* ---- test control ---- */
FAKE_EXPORT int fake_k4a_captures_alive(void) { return g_captures_alive; }

FAKE_EXPORT size_t fake_k4a_layout(const char *name) {
    if (strcmp(name, "version") == 0) return sizeof(k4a_version_t);
    if (strcmp(name, "hardware_version") == 0) return sizeof(k4a_hardware_version_t);
    if (strcmp(name, "hardware_version.depth") == 0) return offsetof(k4a_hardware_version_t, depth);
    if (strcmp(name, "hardware_version.depth_sensor") == 0) return offsetof(k4a_hardware_version_t, depth_sensor);
    if (strcmp(name, "hardware_version.firmware_build") == 0) return offsetof(k4a_hardware_version_t, firmware_build);
    if (strcmp(name, "hardware_version.firmware_signature") == 0) return offsetof(k4a_hardware_version_t, firmware_signature);
    return (size_t)-1;
}
