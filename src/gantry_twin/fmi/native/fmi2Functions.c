/* The FMI 2.0 co-simulation interface of gantry-twin's native plant FMU: the plumbing, once (the split of
 * modelica/Reference-FMUs: the FMI calls here, the model in model.c). It keeps the instance's state (FMI 2.0,
 * section 4.2.4, the co-simulation state machine), checks each call against it, logs what it refuses with the
 * status it returns, and hands the plant's work to model.c. */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "model.h"

typedef enum { INSTANTIATED, INITIALISATION, STEPPING, TERMINATED, FAILED } Phase;

typedef struct {
    Plant plant;
    Phase phase;
    char *name;
    fmi2CallbackFunctions callbacks;
    fmi2Boolean logging;
} Instance;

static const char *const STATUS_CATEGORY[] = {"logStatusOK", "logStatusWarning", "logStatusDiscard",
                                              "logStatusError", "logStatusFatal", "logStatusPending"};

static void say(Instance *c, fmi2Status status, const char *format, ...) {
    /* Errors and warnings always reach the logger; the rest only with logging on. */
    if (!c->callbacks.logger || (status == fmi2OK && !c->logging)) return;
    char text[2048];
    va_list args;
    va_start(args, format);
    vsnprintf(text, sizeof text, format, args);
    va_end(args);
    c->callbacks.logger(c->callbacks.componentEnvironment, c->name, status, STATUS_CATEGORY[status], "%s", text);
}

static fmi2Status refuse(Instance *c, const char *call, Phase allowed_from, Phase allowed_to) {
    /* fmi2Error, logged, for a call the instance's phase does not allow (only phases in [from, to] do). */
    static const char *const WORDS[] = {"instantiated", "in initialisation mode", "in step mode", "terminated",
                                        "in its error state (fmi2Reset or fmi2FreeInstance)"};
    if (c->phase >= allowed_from && c->phase <= allowed_to) return fmi2OK;
    say(c, fmi2Error, "%s: not allowed while the FMU is %s", call, WORDS[c->phase]);
    return fmi2Error;
}

static fmi2Status fail(Instance *c, const char *call, const char *why) {
    c->phase = FAILED;
    say(c, fmi2Error, "%s: %s", call, why);
    return fmi2Error;
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

static const char *resources_path(fmi2String location, char *path, size_t size) {
    /* The resources folder from its URI (file:///a/b, file:/a/b, percent-encoded) or a plain path. */
    const char *at = location;
    if (strncmp(at, "file://", 7) == 0) at += 7;
    else if (strncmp(at, "file:", 5) == 0) at += 5;
    size_t n = 0;
    for (; *at && n + 1 < size; at++) {
        unsigned int byte;
        if (at[0] == '%' && sscanf(at + 1, "%2x", &byte) == 1) {
            path[n++] = (char)byte;
            at += 2;
        } else {
            path[n++] = *at;
        }
    }
    while (n > 1 && path[n - 1] == '/') n--;
    path[n] = '\0';
    return path;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String resources,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible, fmi2Boolean logging) {
    (void)visible;
    if (!functions) return NULL;
    Instance *c = calloc(1, sizeof *c);
    if (!c) return NULL;
    c->callbacks = *functions;
    c->logging = logging;
    c->name = strdup(name ? name : "");
    char path[4096], why[1024];
    if (type != fmi2CoSimulation) {
        snprintf(why, sizeof why, "the FMU is co-simulation only");
    } else if (!guid || strcmp(guid, GP_GUID) != 0) {
        snprintf(why, sizeof why, "guid %s is not this FMU's %s", guid ? guid : "(none)", GP_GUID);
    } else if (!resources) {
        snprintf(why, sizeof why, "no resource location given");
    } else if (model_load(&c->plant, resources_path(resources, path, sizeof path), why, sizeof why) == 0) {
        model_defaults(&c->plant);
        c->phase = INSTANTIATED;
        return c;
    }
    say(c, fmi2Error, "fmi2Instantiate: %s", why);
    free(c->name);
    free(c);
    return NULL;
}

void fmi2FreeInstance(fmi2Component component) {
    Instance *c = component;
    if (!c) return;
    model_free(&c->plant);
    free(c->name);
    free(c);
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String categories[]) {
    (void)n, (void)categories;
    ((Instance *)c)->logging = on;
    return fmi2OK;
}

fmi2Status fmi2SetupExperiment(fmi2Component component, fmi2Boolean has_tolerance, fmi2Real tolerance,
                               fmi2Real start, fmi2Boolean has_stop, fmi2Real stop) {
    (void)has_tolerance, (void)tolerance, (void)has_stop, (void)stop;
    Instance *c = component;
    if (refuse(c, "fmi2SetupExperiment", INSTANTIATED, INSTANTIATED)) return fmi2Error;
    if (start != 0.0) say(c, fmi2Warning, "fmi2SetupExperiment: the plant starts at its own t = 0 s, not %g s",
                          start);
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component component) {
    Instance *c = component;
    if (refuse(c, "fmi2EnterInitializationMode", INSTANTIATED, INSTANTIATED)) return fmi2Error;
    c->phase = INITIALISATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component component) {
    Instance *c = component;
    char why[1024];
    if (refuse(c, "fmi2ExitInitializationMode", INITIALISATION, INITIALISATION)) return fmi2Error;
    if (model_initialise(&c->plant, why, sizeof why)) {
        c->phase = FAILED;
        say(c, fmi2Error, "parameter %s", why);
        return fmi2Error;
    }
    c->phase = STEPPING;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component component) {
    Instance *c = component;
    if (refuse(c, "fmi2Terminate", STEPPING, STEPPING)) return fmi2Error;
    c->phase = TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component component) {
    Instance *c = component;
    model_release(&c->plant);
    model_defaults(&c->plant);
    c->phase = INSTANTIATED;
    return fmi2OK;
}

/* ---- variables --------------------------------------------------------------------------------------------- */

fmi2Status fmi2GetReal(fmi2Component component, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Instance *c = component;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] >= GP_N_VARIABLES) {
            say(c, fmi2Error, "fmi2GetReal: no variable has value reference %u", vr[i]);
            return fmi2Error;
        }
        value[i] = c->plant.values[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component component, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Instance *c = component;
    if (refuse(c, "fmi2SetReal", INSTANTIATED, STEPPING)) return fmi2Error;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] >= GP_N_VARIABLES || vr[i] >= GP_VR_OUTPUTS) {
            say(c, fmi2Error, vr[i] >= GP_N_VARIABLES ? "fmi2SetReal: no variable has value reference %u"
                                                       : "fmi2SetReal: value reference %u is an output", vr[i]);
            return fmi2Error;
        }
        if (vr[i] < GP_N_PARAMETERS && c->phase == STEPPING) {
            say(c, fmi2Error, "fmi2SetReal: %s is a fixed parameter, set before fmi2ExitInitializationMode",
                GP_PARAMETERS[vr[i]].name);
            return fmi2Error;
        }
        c->plant.values[vr[i]] = value[i];
    }
    return fmi2OK;
}

static fmi2Status no_such(fmi2Component component, const char *call, size_t n) {
    if (n == 0) return fmi2OK;
    say(component, fmi2Error, "%s: the FMU has Real variables only", call);
    return fmi2Error;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) {
    (void)vr, (void)v;
    return no_such(c, "fmi2GetInteger", n);
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) {
    (void)vr, (void)v;
    return no_such(c, "fmi2GetBoolean", n);
}
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) {
    (void)vr, (void)v;
    return no_such(c, "fmi2GetString", n);
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) {
    (void)vr, (void)v;
    return no_such(c, "fmi2SetInteger", n);
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) {
    (void)vr, (void)v;
    return no_such(c, "fmi2SetBoolean", n);
}
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) {
    (void)vr, (void)v;
    return no_such(c, "fmi2SetString", n);
}

/* ---- stepping ---------------------------------------------------------------------------------------------- */

fmi2Status fmi2DoStep(fmi2Component component, fmi2Real t, fmi2Real h, fmi2Boolean no_set_prior) {
    (void)no_set_prior;
    Instance *c = component;
    char at[40], step[40], period[40], why[1024];
    if (refuse(c, "fmi2DoStep", STEPPING, STEPPING)) return fmi2Error;
    int samples = model_whole_samples(h), status = MODEL_REFUSED;
    if (samples > 0 && (status = model_step(&c->plant, samples, why, sizeof why)) == 0) return fmi2OK;
    if (samples == 0) {  /* FMI 2.0 has no status for a step size the slave cannot take but fmi2Error */
        model_repr(h, step, sizeof step);
        model_repr(GP_SAMPLE_PERIOD_S, period, sizeof period);
        snprintf(why, sizeof why, "communication step %s s is not a whole multiple of the plant's sample period %s s",
                 step, period);
    }
    model_repr(t, at, sizeof at);
    if (status == MODEL_FAILED) {  /* the plant moved: the instance is in its error state */
        c->phase = FAILED;
    }  /* else nothing moved: the instance may go on with other inputs */
    say(c, fmi2Error, "doStep at t = %s s: %s", at, why);
    return fmi2Error;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    say(c, fmi2Error, "fmi2CancelStep: fmi2DoStep never returns fmi2Pending");
    return fmi2Error;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *v) {
    (void)s, (void)v;
    say(c, fmi2Error, "fmi2GetStatus: fmi2DoStep never returns fmi2Pending");
    return fmi2Discard;
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *v) {
    Instance *i = c;
    if (s == fmi2LastSuccessfulTime) {
        *v = i->plant.time_s;
        return fmi2OK;
    }
    return fmi2GetStatus(c, s, NULL);
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *v) {
    (void)v;
    return fmi2GetStatus(c, s, NULL);
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v) {
    (void)v;
    return fmi2GetStatus(c, s, NULL);
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *v) {
    (void)v;
    return fmi2GetStatus(c, s, NULL);
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr, (void)n, (void)order, (void)value;
    say(c, fmi2Error, "fmi2SetRealInputDerivatives: the inputs are held over a step (canInterpolateInputs false)");
    return fmi2Error;
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr, (void)n, (void)order, (void)value;
    say(c, fmi2Error, "fmi2GetRealOutputDerivatives: not provided (maxOutputDerivativeOrder 0)");
    return fmi2Error;
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real du[], fmi2Real dz[]) {
    (void)u, (void)nu, (void)z, (void)nz, (void)du, (void)dz;
    say(c, fmi2Error, "fmi2GetDirectionalDerivative: not provided (providesDirectionalDerivative false)");
    return fmi2Error;
}

/* ---- the FMU's state: MuJoCo's mj_getState / mj_setState and the plant's own few doubles (model.c) ----------- */

typedef struct {
    size_t size;
    double values[];
} State;

fmi2Status fmi2GetFMUstate(fmi2Component component, fmi2FMUstate *out) {
    Instance *c = component;
    if (refuse(c, "fmi2GetFMUstate", STEPPING, TERMINATED)) return fmi2Error;
    size_t size = model_state_size(&c->plant);
    State *state = *out;
    if (!state || state->size != size) {
        free(state);
        state = malloc(sizeof *state + size * sizeof(double));
        if (!state) return fail(c, "fmi2GetFMUstate", "out of memory");
        state->size = size;
    }
    model_get_state(&c->plant, state->values);
    *out = state;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component component, fmi2FMUstate in) {
    Instance *c = component;
    const State *state = in;
    if (refuse(c, "fmi2SetFMUstate", STEPPING, TERMINATED)) return fmi2Error;
    if (!state || state->size != model_state_size(&c->plant)) {
        say(c, fmi2Error, "fmi2SetFMUstate: not a state of this FMU");
        return fmi2Error;
    }
    model_set_state(&c->plant, state->values);
    c->phase = STEPPING;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    (void)c;
    if (state) {
        free(*state);
        *state = NULL;
    }
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate in, size_t *size) {
    (void)c;
    *size = sizeof(size_t) + ((const State *)in)->size * sizeof(double);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate in, fmi2Byte bytes[], size_t size) {
    const State *state = in;
    size_t need = sizeof(size_t) + state->size * sizeof(double);
    if (size < need) {
        say(c, fmi2Error, "fmi2SerializeFMUstate: %zu bytes given, the state takes %zu", size, need);
        return fmi2Error;
    }
    memcpy(bytes, state, need);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component component, const fmi2Byte bytes[], size_t size,
                                   fmi2FMUstate *out) {
    Instance *c = component;
    size_t count;
    if (refuse(c, "fmi2DeSerializeFMUstate", STEPPING, TERMINATED)) return fmi2Error;
    if (size < sizeof count || (memcpy(&count, bytes, sizeof count), count != model_state_size(&c->plant)) ||
        size != sizeof count + count * sizeof(double)) {
        say(c, fmi2Error, "fmi2DeSerializeFMUstate: %zu bytes are not a state of this FMU", size);
        return fmi2Error;
    }
    State *state = malloc(size);
    if (!state) return fail(c, "fmi2DeSerializeFMUstate", "out of memory");
    memcpy(state, bytes, size);
    free(*out);
    *out = state;
    return fmi2OK;
}
