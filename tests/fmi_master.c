/* A co-simulation master with no Python: dlopen an unpacked FMU's binaries/linux64/GantryPlant.so, instantiate,
 * initialise, and drive the plant with the inputs read from stdin (one line per step: h u_x u_y d_x d_y), writing
 * the eight outputs of each step as %.17g (tests/test_fmi_native.py compares them with the twin's plant).
 *
 *     fmi_master UNPACKED_DIR GUID [NAME=VALUE ...] < steps
 */
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    (void)env, (void)name;
    fprintf(stderr, "[%d %s] %s\n", status, category, message);
}

#define LOAD(f) f##TYPE *f = (f##TYPE *)dlsym(library, #f); if (!f) { fprintf(stderr, "no %s\n", #f); return 2; }

int main(int argc, char **argv) {
    if (argc < 3) return 2;
    char path[4096], resources[4200];
    snprintf(path, sizeof path, "%s/binaries/linux64/GantryPlant.so", argv[1]);
    void *library = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!library) {
        fprintf(stderr, "dlopen: %s\n", dlerror());
        return 2;
    }
    LOAD(fmi2Instantiate) LOAD(fmi2SetupExperiment) LOAD(fmi2EnterInitializationMode)
    LOAD(fmi2ExitInitializationMode) LOAD(fmi2SetReal) LOAD(fmi2GetReal) LOAD(fmi2DoStep) LOAD(fmi2Terminate)
    LOAD(fmi2FreeInstance)
    snprintf(resources, sizeof resources, "file://%s/resources", argv[1]);
    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    fmi2Component c = fmi2Instantiate("plant", fmi2CoSimulation, argv[2], resources, &callbacks, fmi2False, fmi2False);
    if (!c) return 3;
    /* value references by name: the FMU's order (parameters, then u_x_v u_y_v d_x_v d_y_v, then 8 outputs) are
     * passed as NAME=VR:VALUE by the test, which reads them from modelDescription.xml */
    fmi2Status status = fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0);
    status |= fmi2EnterInitializationMode(c);
    unsigned int inputs[4], outputs[8];
    int n_in = 0, n_out = 0;
    for (int i = 3; i < argc; i++) {
        unsigned int vr;
        double value;
        if (sscanf(argv[i], "in=%u", &vr) == 1) inputs[n_in++] = vr;
        else if (sscanf(argv[i], "out=%u", &vr) == 1) outputs[n_out++] = vr;
        else if (sscanf(argv[i], "%u=%lf", &vr, &value) == 2) status |= fmi2SetReal(c, &vr, 1, &value);
    }
    if (n_in != 4 || n_out != 8) return 2;
    status |= fmi2ExitInitializationMode(c);
    if (status != fmi2OK) return 4;
    double t = 0.0, h, u[4], y[8];
    while (scanf("%lf %lf %lf %lf %lf", &h, &u[0], &u[1], &u[2], &u[3]) == 5) {
        if (fmi2SetReal(c, inputs, 4, u) != fmi2OK || fmi2DoStep(c, t, h, fmi2True) != fmi2OK ||
            fmi2GetReal(c, outputs, 8, y) != fmi2OK) {
            printf("refused\n");
            fmi2FreeInstance(c);
            return 5;
        }
        t += h;
        for (int i = 0; i < 8; i++) printf("%.17g%c", y[i], i < 7 ? ' ' : '\n');
    }
    status = fmi2Terminate(c);
    fmi2FreeInstance(c);
    dlclose(library);
    return status == fmi2OK ? 0 : 6;
}
