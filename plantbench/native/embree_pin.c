/* Pin the configuration of Mitsuba's bundled Embree 3 (libembree3.so, its symbols in namespace mitsuba).

   Embree picks its kernels (ISA) and its BVH width ("frequency level") from the CPU it runs on, and its AVX2 kernels
   use the approximate reciprocal vrcpps, whose bits differ between CPU vendors; Mitsuba passes Embree a fixed
   "threads=N,user_threads=N" and Embree reads no configuration file or environment variable. This library, loaded
   with RTLD_GLOBAL before Mitsuba, defines mitsuba::rtcNewDevice, so Mitsuba's call binds here; it appends the
   pinned configuration (set by plantbench_embree_pin) and calls the real function in libembree3.so.
   plantbench.backend.pin_embree builds and loads it; docs/tuning/determinism.md has the measurements. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define REAL_SYMBOL "_ZN7mitsuba12rtcNewDeviceEPKc"

typedef void *(*new_device_fn)(const char *);

static char library[4096];
static char pin[256];
static char last[1024];
static int calls;

/* The real libembree3.so (Mitsuba's, by path) and the configuration to append ("" appends nothing). */
void plantbench_embree_pin(const char *embree_library, const char *config) {
    snprintf(library, sizeof library, "%s", embree_library ? embree_library : "");
    snprintf(pin, sizeof pin, "%s", config ? config : "");
}

/* The configuration the last device was created with, and how many were created through here. */
const char *plantbench_embree_last_config(void) { return last; }
int plantbench_embree_calls(void) { return calls; }

void *_ZN7mitsuba12rtcNewDeviceEPKc(const char *config) {
    static new_device_fn real;
    if (!real) {
        /* Mitsuba has loaded this file already: dlopen returns its handle, and dlsym searches it, not us */
        void *handle = dlopen(library, RTLD_LAZY | RTLD_LOCAL);
        if (handle) real = (new_device_fn)dlsym(handle, REAL_SYMBOL);
        if (!real) {
            fprintf(stderr, "plantbench embree pin: no %s in '%s': %s\n", REAL_SYMBOL, library, dlerror());
            abort();
        }
    }
    const char *given = config ? config : "";
    snprintf(last, sizeof last, "%s%s%s", given, (*given && *pin) ? "," : "", pin);
    calls++;
    return real(last);
}
