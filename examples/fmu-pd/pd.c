/* The twin's built-in pd law (src/gantry_twin/controllers/pd.py) as an FMI 2.0 co-simulation FMU (docs/fmi.md).
   Per axis: u = -kp e - kd e' + kv x_d' + ka x_d'' with e = x - x_d, in the same order of operations as pd.py. */
#include <stdlib.h>
#include "fmi2Functions.h"
#ifndef TERMINATE_STATUS /* the tests' failing controller sets it */
#define TERMINATE_STATUS fmi2OK
#endif

enum { X_M, Y_M, DX_M_S, DY_M_S, X_D_M, Y_D_M, DX_D_M_S, DY_D_M_S, DDX_D_M_S2, DDY_D_M_S2, /* inputs */
       U_X_V, U_Y_V,                                                                    /* outputs, volts */
       KP_X, KP_Y, KD_X, KD_Y, KV_X, KV_Y, KA_X, KA_Y, N_VARS };                        /* parameters */
static const double START[N_VARS] = {[KP_X] = 1e4, [KP_Y] = 1e4, [KD_X] = 100, [KD_Y] = 100,
                                     [KV_X] = 0.5, [KV_Y] = 0.7, [KA_X] = 0.12, [KA_Y] = 0.5};

#if defined(MISBEHAVE_AT_S) || defined(MISBEHAVE_ON_START) /* the tests' misbehaving controllers (docs/fmi.md):
   doStep from MISBEHAVE_AT_S on, or fmi2Instantiate */
#include <string.h>
#define SEGFAULT 1 /* MISBEHAVE: what doStep does */
#define ABORT 2
#define EXIT 3
#define ENDLESS 4
#define LEAK 5
static void *volatile leaked;
static void misbehave(void) {
#if MISBEHAVE == SEGFAULT
    *(volatile int *)0 = 1;
#elif MISBEHAVE == ABORT
    abort();
#elif MISBEHAVE == EXIT
    exit(3);
#elif MISBEHAVE == ENDLESS
    for (volatile int spin = 1; spin;) {}
#elif MISBEHAVE == LEAK /* 1 MiB a step, written and never freed */
    leaked = memset(malloc(1 << 20), 1, 1 << 20);
#endif
}
#endif

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    double *v = c;
#ifdef FAIL_AT_S /* the tests' failing controller: doStep returns FAIL_STATUS from FAIL_AT_S on */
    if (t >= FAIL_AT_S) return FAIL_STATUS;
#endif
#ifdef MISBEHAVE_AT_S
    if (t >= MISBEHAVE_AT_S) misbehave();
#endif
    for (int i = 0; i < 2; i++) {
        double e = v[X_M + i] - v[X_D_M + i], de = v[DX_M_S + i] - v[DX_D_M_S + i];
        v[U_X_V + i] = -v[KP_X + i] * e - v[KD_X + i] * de + v[KV_X + i] * v[DX_D_M_S + i] + v[KA_X + i] * v[DDX_D_M_S2 + i];
    }
    return fmi2OK;
}
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    for (size_t i = 0; i < n; i++) { if (vr[i] >= N_VARS) return fmi2Error; ((double *)c)[vr[i]] = value[i]; }
    return fmi2OK;
}
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    for (size_t i = 0; i < n; i++) { if (vr[i] >= N_VARS) return fmi2Error; value[i] = ((double *)c)[vr[i]]; }
    return fmi2OK;
}
fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String resources,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible, fmi2Boolean loggingOn) {
#ifdef MISBEHAVE_ON_START
    misbehave();
#endif
    double *v = calloc(N_VARS, sizeof(double));
    for (int i = 0; v && i < N_VARS; i++) v[i] = START[i];
    return v;
}
void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2Terminate(fmi2Component c) { return TERMINATE_STATUS; }

/* The rest of FMI 2.0: nothing to do, or not offered. */
#define OK(f, ...) fmi2Status f(__VA_ARGS__) { return fmi2OK; }
#define NO(f, ...) fmi2Status f(__VA_ARGS__) { return fmi2Error; }
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }
OK(fmi2SetDebugLogging, fmi2Component c, fmi2Boolean on, size_t n, const fmi2String categories[])
OK(fmi2SetupExperiment, fmi2Component c, fmi2Boolean tolDefined, fmi2Real tol, fmi2Real start, fmi2Boolean stopDefined, fmi2Real stop)
OK(fmi2EnterInitializationMode, fmi2Component c)
OK(fmi2ExitInitializationMode, fmi2Component c)
OK(fmi2Reset, fmi2Component c)
NO(fmi2GetInteger, fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer value[])
NO(fmi2GetBoolean, fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean value[])
NO(fmi2GetString, fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String value[])
NO(fmi2SetInteger, fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer value[])
NO(fmi2SetBoolean, fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean value[])
NO(fmi2SetString, fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String value[])
NO(fmi2GetFMUstate, fmi2Component c, fmi2FMUstate *s)
NO(fmi2SetFMUstate, fmi2Component c, fmi2FMUstate s)
NO(fmi2FreeFMUstate, fmi2Component c, fmi2FMUstate *s)
NO(fmi2SerializedFMUstateSize, fmi2Component c, fmi2FMUstate s, size_t *size)
NO(fmi2SerializeFMUstate, fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t size)
NO(fmi2DeSerializeFMUstate, fmi2Component c, const fmi2Byte b[], size_t size, fmi2FMUstate *s)
NO(fmi2GetDirectionalDerivative, fmi2Component c, const fmi2ValueReference u[], size_t nu, const fmi2ValueReference z[],
   size_t nz, const fmi2Real du[], fmi2Real dz[])
NO(fmi2SetRealInputDerivatives, fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[], const fmi2Real v[])
NO(fmi2GetRealOutputDerivatives, fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[], fmi2Real v[])
NO(fmi2CancelStep, fmi2Component c)
NO(fmi2GetStatus, fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
NO(fmi2GetRealStatus, fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
NO(fmi2GetIntegerStatus, fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
NO(fmi2GetBooleanStatus, fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
NO(fmi2GetStringStatus, fmi2Component c, const fmi2StatusKind s, fmi2String *value)
