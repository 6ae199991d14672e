/* gantry-twin's plant, the model behind the native FMU (model.h; docs/fmi.md, "The plant as an FMU").
 *
 * The equations here are the twin's own, line for line, in the order the twin computes them, so that the FMU
 * gives the twin's numbers to the bit (tests/test_fmi_native.py pins them): one sample is
 * src/gantry_twin/loop/sample.py's advance_plant (record_and_step, then measure_sample), with the plant's input
 * offset and force ripple of src/gantry_twin/plant/effects.py (plant_input_v) and the encoder of
 * src/gantry_twin/plant/sensing.py (encoder_measure); the machine is built as plant/model.py's build_spec and
 * plant/friction.py's apply_friction build it (the export writes their MJCF, this file only puts the parameters
 * in), and the parameters are refused with fmi/plant.py's build_plant's words. Compiled without fused
 * multiply-add (-ffp-contract=off), as numba's code rounds. */
#include "model.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <mujoco/mujoco.h>

static const char *const AXES[2] = {"x", "y"};

static void say(char *error, size_t size, const char *format, ...) {
    va_list args;
    va_start(args, format);
    vsnprintf(error, size, format, args);
    va_end(args);
}

void model_repr(double x, char *out, size_t size) {
    /* Python's repr of a float: the shortest digits that read back as x; positional from 1e-4 to 1e16. */
    if (isnan(x)) { snprintf(out, size, "nan"); return; }
    if (isinf(x)) { snprintf(out, size, x > 0 ? "inf" : "-inf"); return; }
    char text[40], digits[24];
    int precision;
    for (precision = 1; precision <= 17; precision++) {
        snprintf(text, sizeof text, "%.*e", precision - 1, x);
        if (strtod(text, NULL) == x) break;
    }
    const char *at = text + (text[0] == '-');
    int n = 0;
    for (; *at && *at != 'e'; at++) if (*at != '.') digits[n++] = *at;
    int exponent = atoi(at + 1);
    while (n > 1 && digits[n - 1] == '0') n--;
    digits[n] = '\0';
    const char *sign = signbit(x) ? "-" : "";
    if (exponent < -4 || exponent >= 16) {
        snprintf(out, size, "%s%c%s%.*s%c%c%02d", sign, digits[0], n > 1 ? "." : "", n - 1, digits + 1,
                 'e', exponent < 0 ? '-' : '+', abs(exponent));
    } else if (exponent >= 0) {
        char whole[24], fraction[24];
        for (int i = 0; i <= exponent; i++) whole[i] = i < n ? digits[i] : '0';
        whole[exponent + 1] = '\0';
        snprintf(fraction, sizeof fraction, "%s", n > exponent + 1 ? digits + exponent + 1 : "0");
        snprintf(out, size, "%s%s.%s", sign, whole, fraction);
    } else {
        snprintf(out, size, "%s0.%0*d%s", sign, -exponent - 1, 0, digits);
        if (exponent == -1) snprintf(out, size, "%s0.%s", sign, digits);
    }
}

void model_defaults(Plant *p) {
    memcpy(p->values, GP_START, sizeof p->values);
}

int model_load(Plant *p, const char *resources, char *error, size_t size) {
    char path[4096], why[1024] = "";
    snprintf(path, sizeof path, "%s/%s", resources, GP_MODEL_FILE);
    p->spec = mj_parseXML(path, NULL, why, sizeof why);
    if (!p->spec) {
        say(error, size, "cannot read the machine %s: %s", path, why);
        return -1;
    }
    return 0;
}

/* ---- the parameters: checked in build_plant's order and words, then put into the spec ---------------------- */

static int refuse_out_of_range(const Plant *p, int vr, char *error, size_t size) {
    const GpParameter *q = &GP_PARAMETERS[vr];
    double x = p->values[vr];
    int bad = !isfinite(x);
    if (q->kind == GP_RANGE) bad = bad || (q->lo_open ? x <= q->lo : x < q->lo) || x > q->hi;
    if (q->kind == GP_NONNEGATIVE) bad = bad || !(x >= 0.0);
    if (!bad) return 0;
    char value[40];
    model_repr(x, value, sizeof value);
    say(error, size, "%s: %s, got %s", q->name, q->allowed, value);
    return -1;
}

static int refuse_lugre(const Plant *p, int axis, char *error, size_t size) {
    /* plant/friction.py's physical_problem: the pre-sliding distance and Fs / Fc. */
    double sigma0 = p->values[GP_VR_SIGMA0[axis]], fc = p->values[GP_VR_FC[axis]], fs = p->values[GP_VR_FS[axis]];
    if (!(GP_PRESLIDING_MIN_M <= fc / sigma0 && fc / sigma0 <= GP_PRESLIDING_MAX_M)) {
        say(error, size, "friction.%s.sigma0_n_m: the pre-sliding distance Fc / sigma0 must be in [%g, %g] um, "
            "got %g um (Fc = %g N)", AXES[axis], GP_PRESLIDING_MIN_M * 1e6, GP_PRESLIDING_MAX_M * 1e6,
            fc / sigma0 * 1e6, fc);
        return -1;
    }
    if (!(GP_STRIBECK_MIN <= fs / fc && fs / fc <= GP_STRIBECK_MAX)) {
        say(error, size, "friction.%s.fs_n: the ratio Fs / Fc must be in [%g, %g], got %g / %g N", AXES[axis],
            GP_STRIBECK_MIN, GP_STRIBECK_MAX, fs, fc);
        return -1;
    }
    return 0;
}

static int check_parameters(const Plant *p, char *error, size_t size) {
    for (int i = 0; i < GP_N_CHECKS; i++) {
        int vr = GP_CHECK_ORDER[i];
        if (vr == GP_CHECK_LUGRE_X || vr == GP_CHECK_LUGRE_Y) {
            if (refuse_lugre(p, vr == GP_CHECK_LUGRE_Y, error, size)) return -1;
        } else if (refuse_out_of_range(p, vr, error, size)) {
            return -1;
        }
    }
    return 0;
}

static void *element(mjSpec *spec, mjtObj type, const char *name, char *error, size_t size) {
    mjsElement *found = mjs_findElement(spec, type, name);
    if (!found) say(error, size, "resources/%s has no %s named '%s'", GP_MODEL_FILE,
                    type == mjOBJ_BODY ? "body" : type == mjOBJ_JOINT ? "joint" :
                    type == mjOBJ_GEOM ? "geom" : "actuator", name);
    return found;
}

static int put_parameters(Plant *p, char *error, size_t size) {
    /* plant/model.py's build_spec (the payload block, always present in the export's MJCF) and
     * plant/friction.py's apply_friction (the joints' damping and frictionloss, the LuGre actuators). */
    mjSpec *spec = p->spec;
    double mass = p->values[GP_VR_PAYLOAD], side = GP_PAYLOAD_SIDE_M;
    mjsElement *found = element(spec, mjOBJ_BODY, "payload", error, size);
    if (!found) return -1;
    mjsBody *body = mjs_asBody(found);
    double height = fmax(mass / (GP_PAYLOAD_DENSITY_KG_M3 * side * side), GP_PAYLOAD_MIN_HEIGHT_M);
    double i_xy = mass * (pow(side, 2.0) + pow(height, 2.0)) / 12.0;
    body->explicitinertial = 1;
    body->mass = mass;
    body->inertia[0] = i_xy;
    body->inertia[1] = i_xy;
    body->inertia[2] = mass * 2 * pow(side, 2.0) / 12.0;
    if (!(found = element(spec, mjOBJ_GEOM, "payload_box", error, size))) return -1;
    mjsGeom *box = mjs_asGeom(found);
    box->size[0] = side / 2;
    box->size[1] = side / 2;
    box->size[2] = height / 2;
    for (int i = 0; i < 2; i++) {
        if (!(found = element(spec, mjOBJ_JOINT, AXES[i], error, size))) return -1;
        mjsJoint *joint = mjs_asJoint(found);
        joint->damping[0] = p->values[GP_VR_SIGMA2[i]];
        if (!GP_LUGRE) {
            joint->frictionloss = p->values[GP_VR_FC[i]];
            continue;
        }
        char name[32];
        snprintf(name, sizeof name, GP_FRICTION_ACTUATOR, AXES[i]);
        if (!(found = element(spec, mjOBJ_ACTUATOR, name, error, size))) return -1;
        mjsActuator *motor = mjs_asActuator(found);
        double constants[2] = {0.0, 0.0};
        double lugre[5] = {p->values[GP_VR_SIGMA0[i]], p->values[GP_VR_SIGMA1[i]], p->values[GP_VR_FC[i]],
                           p->values[GP_VR_FS[i]], p->values[GP_VR_VS[i]]};
        const char *why = mjs_setToDCMotor(motor, constants, 1.0, NULL, NULL, NULL, NULL, NULL, NULL, lugre,
                                           mjINPUT_NONE);
        if (why && *why) {
            say(error, size, "friction.%s: %s", AXES[i], why);
            return -1;
        }
        motor->gear[0] = 1.0;
        motor->ctrllimited = 0;
        motor->damping[0] = motor->damping[1] = motor->damping[2] = 0.0;
    }
    spec->option.timestep = GP_SAMPLE_PERIOD_S / GP_SUBSTEPS;
    return 0;
}

static int check_bristle_damping(const Plant *p, char *error, size_t size) {
    /* plant/friction.py's check_bristle_damping: sigma1 at most 2 sqrt(sigma0 M), M from mj_fullM at qpos0. */
    const mjModel *m = p->m;
    mjData *d = mj_makeData(m);
    mjtNum *full = calloc((size_t)m->nv * m->nv, sizeof *full);
    int refused = 0;
    mj_forward(m, d);
    mj_fullM(m, d, full);
    for (int i = 0; i < 2 && !refused; i++) {
        int a = p->friction[i];
        if (a < 0) continue;
        double mass = full[p->dof[i] * m->nv + p->dof[i]];
        double sigma0 = m->actuator_dynprm[a * mjNDYN + 5], sigma1 = m->actuator_dynprm[a * mjNDYN + 6];
        double critical = 2.0 * sqrt(sigma0 * mass);
        if (sigma1 > critical) {
            say(error, size, "friction.%s.sigma1_ns_m: must be at most the critical damping 2 sqrt(sigma0 M) = %g "
                "N s/m (M = %g kg), got %g", AXES[i], critical, mass, sigma1);
            refused = 1;
        }
    }
    free(full);
    mj_deleteData(d);
    return refused ? -1 : 0;
}

/* ---- one sample (loop/sample.py, plant/effects.py, plant/sensing.py) ----------------------------------------- */

static double clip(double value, double lower, double upper) {
    /* numerics/estimation.py's clip: NaN passes through. */
    if (value > upper) return upper;
    if (value < lower) return lower;
    return value;
}

static double plant_input_v(int axis, double q_m) {
    /* plant/effects.py's plant_input_v: the offset dN(q) plus the force ripple at the true position, V. */
    const double *table = GP_INPUT_TABLE[axis];
    double out = table[0] + table[1] * q_m;
    double w = 2.0 * M_PI * q_m / table[2];
    for (int k = 0; k < GP_RIPPLE_HARMONICS; k++) {
        double amplitude = table[3 + 2 * k];
        if (amplitude != 0.0) out += amplitude * sin((k + 1) * w + table[4 + 2 * k]);
    }
    return out;
}

static double encoder_read(double q_m) {
    /* plant/sensing.py's encoder_read: the nearest count, ties to even. */
    return GP_QUANTIZE ? rint(q_m / GP_RESOLUTION_M) * GP_RESOLUTION_M : q_m;
}

static int measure(Plant *p) {
    /* loop/sample.py's measure_sample with plant/sensing.py's encoder_measure (no glitches); 0 if not finite. */
    double *out = p->values + GP_VR_OUTPUTS;
    int finite = 1;
    for (int i = 0; i < 2; i++) {
        double q = p->d->qpos[p->qpos[i]], dq = p->d->qvel[p->dof[i]];
        out[4 + i] = q;
        out[6 + i] = dq;
        out[i] = encoder_read(q);
        out[2 + i] = GP_VELOCITY_BY_DIFFERENCE ? (out[i] - p->previous_m[i]) / GP_SAMPLE_PERIOD_S : dq;
        p->previous_m[i] = out[i];
        finite = finite && isfinite(out[i]) && isfinite(out[2 + i]);
    }
    return finite;
}

static int record_and_step(Plant *p) {
    /* loop/sample.py's record_and_step without amplifier, cogging or recording; 0 if the command is not finite. */
    const double *u = p->values + GP_VR_U, *d = p->values + GP_VR_D;
    for (int i = 0; i < 2; i++) if (!isfinite(u[i])) return 0;
    mjtNum *ctrl = p->d->ctrl;
    for (int i = 0; i < 2; i++) {
        ctrl[p->motor[i]] = clip(u[i], -p->u_max_v[i], p->u_max_v[i]);
        ctrl[p->disturbance[i]] = d[i];
        ctrl[p->disturbance[i]] += plant_input_v(i, p->values[GP_VR_OUTPUTS + 4 + i]);
    }
    for (int s = 0; s < GP_SUBSTEPS; s++) mj_step(p->m, p->d);
    return 1;
}

int model_whole_samples(double step_s) {
    /* fmi/plant.py's whole_samples. */
    if (!isfinite(step_s) || step_s <= 0.0) return 0;
    double count = nearbyint(step_s / GP_SAMPLE_PERIOD_S);
    if (count < 1 || count > 1e9 || !(fabs(step_s / GP_SAMPLE_PERIOD_S - count) <= 1e-9 * count)) return 0;
    return (int)count;
}

int model_step(Plant *p, int samples, char *error, size_t size) {
    /* fmi/plant.py's CoSimPlant.advance: the disturbance checked, then `samples` samples. */
    const double *d = p->values + GP_VR_D;
    if (!isfinite(d[0]) || !isfinite(d[1])) {
        char x[40], y[40];
        model_repr(d[0], x, sizeof x);
        model_repr(d[1], y, sizeof y);
        say(error, size, "disturbance (%s, %s) V is not finite", x, y);
        return MODEL_REFUSED;
    }
    for (int k = 0; k < samples; k++) {
        if (!record_and_step(p)) {  /* the command is held over the step: refused at its first sample */
            say(error, size, "non-finite command after %d samples of the step", k);
            p->time_s += k * GP_SAMPLE_PERIOD_S;
            return k == 0 ? MODEL_REFUSED : MODEL_FAILED;
        }
        if (!measure(p)) {
            say(error, size, "non-finite measurement after %d samples of the step", k);
            p->time_s += k * GP_SAMPLE_PERIOD_S;
            return MODEL_FAILED;
        }
    }
    p->time_s += samples * GP_SAMPLE_PERIOD_S;
    return 0;
}

/* ---- initialisation ------------------------------------------------------------------------------------------ */

static int find(const mjModel *m, int type, const char *format, int axis, char *error, size_t size) {
    char name[32];
    snprintf(name, sizeof name, format, AXES[axis]);
    int id = mj_name2id(m, type, name);
    if (id < 0 && type != mjOBJ_ACTUATOR) say(error, size, "resources/%s has no '%s'", GP_MODEL_FILE, name);
    return id;
}

static double steady_bristle_m(const mjModel *m, int actuator, double v_m_s) {
    /* plant/friction.py's steady_bristle_m: sign(v) g(v) / sigma0, 0 at rest. */
    if (v_m_s == 0.0) return 0.0;
    const mjtNum *dyn = m->actuator_dynprm + actuator * mjNDYN, *bias = m->actuator_biasprm + actuator * mjNBIAS;
    double fc = bias[3], fs = bias[4], vs = bias[5], r = v_m_s / vs;
    double g = fc + (fs - fc) * exp(-(r * r));
    return (v_m_s > 0.0 ? g : -g) / dyn[5];
}

int model_initialise(Plant *p, char *error, size_t size) {
    if (check_parameters(p, error, size) || put_parameters(p, error, size)) return -1;
    model_release(p);
    p->m = mj_compile(p->spec, NULL);
    if (!p->m) {
        say(error, size, "MuJoCo cannot compile the machine: %s", mjs_getError(p->spec));
        return -1;
    }
    for (int i = 0; i < 2; i++) {
        int joint = find(p->m, mjOBJ_JOINT, "%s", i, error, size);
        if (joint < 0) return -1;
        p->qpos[i] = p->m->jnt_qposadr[joint];
        p->dof[i] = p->m->jnt_dofadr[joint];
        if ((p->motor[i] = find(p->m, mjOBJ_ACTUATOR, "%s_motor", i, error, size)) < 0 ||
            (p->disturbance[i] = find(p->m, mjOBJ_ACTUATOR, "%s_disturbance", i, error, size)) < 0) {
            say(error, size, "resources/%s lacks %s's motors", GP_MODEL_FILE, AXES[i]);
            return -1;
        }
        p->friction[i] = find(p->m, mjOBJ_ACTUATOR, GP_FRICTION_ACTUATOR, i, error, size);
        p->u_max_v[i] = p->m->actuator_ctrlrange[2 * p->motor[i] + 1];
    }
    if (check_bristle_damping(p, error, size)) return -1;
    p->d = mj_makeData(p->m);
    /* plant/model.py's Plant.reset: at start.* at rest or moving, the bristles as in steady sliding. */
    const double *start = p->values + GP_VR_START;
    mj_resetData(p->m, p->d);
    for (int i = 0; i < 2; i++) {
        p->d->qpos[p->qpos[i]] = start[i];
        p->d->qvel[p->dof[i]] = start[2 + i];
    }
    for (int i = 0; i < 2; i++) {
        int a = p->friction[i];
        if (a >= 0) p->d->act[p->m->actuator_actadr[a]] = steady_bristle_m(p->m, a, start[2 + i]);
    }
    mj_forward(p->m, p->d);
    /* plant/sensing.py's encoder_reset: as if moving at start.d* before t = 0; then the reading at t = 0. */
    for (int i = 0; i < 2; i++) p->previous_m[i] = encoder_read(start[i] - start[2 + i] * GP_SAMPLE_PERIOD_S);
    measure(p);
    p->time_s = 0.0;
    return 0;
}

void model_release(Plant *p) {
    if (p->d) mj_deleteData(p->d);
    if (p->m) mj_deleteModel(p->m);
    p->d = NULL;
    p->m = NULL;
}

void model_free(Plant *p) {
    model_release(p);
    if (p->spec) mj_deleteSpec(p->spec);
    p->spec = NULL;
}

/* ---- the state: mj_getState's integration state, the encoder, the time and the variables ---------------------- */

size_t model_state_size(const Plant *p) {
    return (size_t)mj_stateSize(p->m, mjSTATE_INTEGRATION) + 3 + GP_N_VARIABLES;
}

void model_get_state(const Plant *p, double *state) {
    mj_getState(p->m, p->d, state, mjSTATE_INTEGRATION);
    state += mj_stateSize(p->m, mjSTATE_INTEGRATION);
    state[0] = p->previous_m[0];
    state[1] = p->previous_m[1];
    state[2] = p->time_s;
    memcpy(state + 3, p->values, sizeof p->values);
}

void model_set_state(Plant *p, const double *state) {
    mj_setState(p->m, p->d, state, mjSTATE_INTEGRATION);
    state += mj_stateSize(p->m, mjSTATE_INTEGRATION);
    p->previous_m[0] = state[0];
    p->previous_m[1] = state[1];
    p->time_s = state[2];
    memcpy(p->values, state + 3, sizeof p->values);
}
