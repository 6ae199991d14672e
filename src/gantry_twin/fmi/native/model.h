/* gantry-twin's plant as a native FMU: the model's side (docs/fmi.md, "The plant as an FMU").
 *
 * model.c holds the plant: the machine's MJCF compiled with MuJoCo's C API, the parameters checked and put
 * into it, and each 0.2 ms sample (the DAC clip, the disturbance input, the rig's input offset and force
 * ripple, MuJoCo's steps, the encoder's quantisation and backward-difference velocity). fmi2Functions.c is
 * the FMI 2.0 plumbing around it and knows nothing of the plant; config.h is written by the export
 * (src/gantry_twin/fmi/plant_native.py): the machine's constants and the variables' table. */
#ifndef GANTRY_PLANT_MODEL_H
#define GANTRY_PLANT_MODEL_H

#include <stddef.h>

#include "config.h"

typedef struct mjModel_ mjModel;
typedef struct mjData_ mjData;
typedef struct mjSpec_ mjSpec;

/* One instance of the plant: every FMI variable by value reference, MuJoCo's model and data, the encoder. */
typedef struct {
    double values[GP_N_VARIABLES];  /* parameters, inputs (V), outputs (m, m/s), by value reference */
    mjSpec *spec;                   /* resources/model.xml, parsed at instantiation */
    mjModel *m;                     /* compiled at initialisation, with the parameters as set */
    mjData *d;
    int qpos[2], dof[2], motor[2], disturbance[2], friction[2];  /* X, Y; friction -1 on a Coulomb plant */
    double u_max_v[2];              /* the DAC's limit, the control motors' ctrlrange, V */
    double previous_m[2];           /* the encoder's last reading, m */
    double time_s;                  /* the plant's own time: whole samples done */
} Plant;

/* The parameters' and inputs' start values (the export's defaults). */
void model_defaults(Plant *p);
/* Parse resources/model.xml; 0, or -1 with the reason in `error`. */
int model_load(Plant *p, const char *resources, char *error, size_t size);
/* Check the parameters, compile the machine with them, start it at start.*; 0, or -1 with the reason. */
int model_initialise(Plant *p, char *error, size_t size);
/* `samples` samples with the inputs held: 0; MODEL_REFUSED with the reason, nothing changed (a non-finite
 * input); MODEL_FAILED with the reason, the plant moved (the outputs are those of its last sample). */
enum { MODEL_REFUSED = 1, MODEL_FAILED = 2 };
int model_step(Plant *p, int samples, char *error, size_t size);
/* The communication step `step_s` as a count of whole samples, or 0 unless it is one (to a relative 1e-9). */
int model_whole_samples(double step_s);
/* Drop the compiled machine (the parsed file stays); model_free also drops the file. */
void model_release(Plant *p);
void model_free(Plant *p);

/* The plant's state: MuJoCo's integration state, the encoder, the time and every variable, as doubles. */
size_t model_state_size(const Plant *p);
void model_get_state(const Plant *p, double *state);
void model_set_state(Plant *p, const double *state);

/* x as Python's repr() writes a float (the messages are the Python FMU's, word for word). */
void model_repr(double x, char *out, size_t size);

#endif
