/* The cost of the native plant FMU seen from a C master (benchmarks/bench_fmi.py, the plant part): pd closed
 * around the FMU at every 0.2 ms sample, as the twin's loop closes it, with no Python in the process.
 *
 *     fmi_plant_master UNPACKED_DIR GUID REFERENCE_FILE VR...
 *
 * REFERENCE_FILE: n rows of 6 doubles (q_d x y, dq_d x y, ddq_d x y), raw; then pd's gains kp kd kv_x kv_y ka_x ka_y
 * as one more row. VR: the value references of start.x_m start.y_m start.dx_m_s start.dy_m_s, x_m y_m dx_m_s
 * dy_m_s, u_x_v u_y_v. Prints "samples cpu_s": the process's CPU (every thread) over the loop alone. */
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    (void)env, (void)name, (void)category;
    fprintf(stderr, "[%d] %s\n", status, message);
}

#define LOAD(f) f##TYPE *f = (f##TYPE *)dlsym(library, #f); if (!f) return 2;

static double clip(double u) { return u > 10.0 ? 10.0 : u < -10.0 ? -10.0 : u; }

int main(int argc, char **argv) {
    if (argc != 14) return 2;
    char path[4096], resources[4200];
    snprintf(path, sizeof path, "%s/binaries/linux64/GantryPlant.so", argv[1]);
    void *library = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!library) return 3;
    LOAD(fmi2Instantiate) LOAD(fmi2SetupExperiment) LOAD(fmi2EnterInitializationMode)
    LOAD(fmi2ExitInitializationMode) LOAD(fmi2SetReal) LOAD(fmi2GetReal) LOAD(fmi2DoStep) LOAD(fmi2FreeInstance)
    FILE *file = fopen(argv[3], "rb");
    if (!file) return 4;
    fseek(file, 0, SEEK_END);
    long rows = ftell(file) / (long)(6 * sizeof(double)) - 1;
    fseek(file, 0, SEEK_SET);
    double *ref = malloc((size_t)(rows + 1) * 6 * sizeof(double));
    if (!ref || fread(ref, 6 * sizeof(double), (size_t)rows + 1, file) != (size_t)rows + 1) return 4;
    fclose(file);
    const double *gains = ref + rows * 6;
    unsigned int vr[10];
    for (int i = 0; i < 10; i++) vr[i] = (unsigned int)strtoul(argv[4 + i], NULL, 10);
    snprintf(resources, sizeof resources, "file://%s/resources", argv[1]);
    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    fmi2Component c = fmi2Instantiate("plant", fmi2CoSimulation, argv[2], resources, &callbacks, fmi2False, fmi2False);
    if (!c) return 5;
    double start[4] = {ref[0], ref[1], ref[2], ref[3]};
    if (fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) || fmi2EnterInitializationMode(c) ||
        fmi2SetReal(c, vr, 4, start) || fmi2ExitInitializationMode(c))
        return 6;
    struct timespec t0, t1;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t0);
    double y[4], u[2];
    for (long k = 0; k < rows; k++) {
        const double *r = ref + 6 * k;
        if (fmi2GetReal(c, vr + 4, 4, y)) return 7;
        for (int i = 0; i < 2; i++)
            u[i] = clip(-gains[0] * (y[i] - r[i]) - gains[1] * (y[2 + i] - r[2 + i]) + gains[2 + i] * r[2 + i] +
                        gains[4 + i] * r[4 + i]);
        if (fmi2SetReal(c, vr + 8, 2, u) || fmi2DoStep(c, k * 2e-4, 2e-4, fmi2True)) return 8;
    }
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t1);
    printf("%ld %.9f\n", rows, (double)(t1.tv_sec - t0.tv_sec) + 1e-9 * (double)(t1.tv_nsec - t0.tv_nsec));
    fmi2FreeInstance(c);
    return 0;
}
