/* What `needlesim run` needs from a scenario beyond its tissue: the needle, the entry, the
 * targets, the time step and duration, and whether it has a script or an on_tick. The Lua side
 * (scripts/needlesim.lua: ns.needle, ns.scenario) has checked every field's type and range;
 * this reads them into C and checks what needs the mesh (a target inside the tissue). */
#ifndef NS_RUN_SPEC_H
#define NS_RUN_SPEC_H

#include <stdbool.h>

#include "control_log.h"
#include "scenario.h"

typedef struct NsRunTarget {
    char *name;
    double at[3];     /* material (= initial world) position [m] */
    double tolerance; /* [m] */
} NsRunTarget;

/* A tissue point whose world position is logged (a phantom's fiducial). */
typedef struct NsRunMarker {
    char *name;
    double at[3]; /* material position [m] */
} NsRunMarker;

/* A tissue region the needle must not enter. */
typedef struct NsRunObstacle {
    char *name;
    int region; /* index into the scenario's regions */
} NsRunObstacle;

/* camera = {...}: what frames and videos show (docs/rendering.md). */
typedef struct NsRunCamera {
    int views[3]; /* NsView (render/scene.h): 0 side, 1 top, 2 axis */
    int view_count;
    double fps;
    int frame_every; /* steps between frames */
    bool has_cut_normal;
    double cut_normal[3];
    bool tet_edges, friction_colours;
} NsRunCamera;

/* dosimetry = {...} (docs/brachytherapy.md): the seeds' TG-43 dose, planned against delivered. */
typedef struct NsRunDosimetry {
    bool on;
    double prescription; /* [Gy] */
    double strength;     /* each seed's air-kerma strength S_K [Gy m^2 s^-1] */
    double spacing;      /* the dose grid's [m] */
    int region[3];       /* prostate, urethra, rectum: indices into the scenario's regions */
    double *plan;        /* the planned seed centres in the undeformed anatomy (plan_n x 3) [m] */
    int plan_n;
} NsRunDosimetry;

typedef struct NsRunSpec {
    /* ns.needle{} (the stiff default when the scenario has none) */
    char *needle_kind;
    double diameter, inner_diameter, youngs, density; /* SI */
    bool bevel;
    double bevel_deg;
    int steering;         /* steering = "force" | "displacement" | "arc": an NsBevelModel */
    double arc_curvature; /* its curvature at tan(psi) = 1 [1/m] */
    double bevel_force;   /* the force model's k_b: lateral tip force at tan(psi) = 1 [N] */
    bool twist_friction;  /* torsional friction with the tissue (sim/twist_friction.h) */
    /* entry = {point, direction} (direction of unit length) */
    double entry_point[3], entry_dir[3];
    bool has_bevel_toward;
    double bevel_toward[3]; /* unit, normal to entry_dir: where a bevel tip steers at first */
    NsRunTarget *targets;
    int target_count;
    NsRunMarker *markers;
    int marker_count;
    NsRunObstacle *obstacles;
    int obstacle_count;
    int *seed_target; /* the seed plan: the target index of each planned seed */
    int seed_count;
    double dt;       /* [s]: the scenario's, else 0.01 */
    double duration; /* [s]: the scenario's, else 0 (until the script ends) */
    bool has_script, has_on_tick;
    NsRunCamera camera;
    /* solver = {...}: <= 0 where the scenario leaves the engine's default */
    double tolerance, check_tolerance, lazy_threshold;
    bool tip_block; /* solver = {tip_block = true} (docs/solvers.md, "The tail") */
    /* accuracy = ...: the tip accuracy asked for [m] (0: none), the front's setting chosen and
     * its measured tip error [m] and cost [ms per simulated s] */
    double accuracy, accuracy_tip_error, accuracy_cost;
    char accuracy_front[32], accuracy_label[96];
    /* dt and the solver settings above chosen apart from the scenario (live --accuracy, or a
     * replayed log's #model): the control log records them */
    bool model_chosen;
    /* live = {script, entries, accuracy, front} (docs/live.md): a live session runs the script
     * first only with live_script; {"next_needle": true} takes live_entries in turn (none: the
     * entry above) */
    bool live_script;
    double live_accuracy; /* live.accuracy [m] (0: none): the live session's model, as --accuracy */
    char live_front[32];  /* live.front: the measured front it is looked up on */
    NsEntry *live_entries;
    int live_entry_count;
    NsRunDosimetry dosimetry;
} NsRunSpec;

/* Reads sc's run fields. Returns 0, or -1 with one line naming the scenario's file and line
 * and the field; spec is then freed. */
int ns_run_spec_read(const NsScenario *sc, NsRunSpec *spec, char *err, int err_sz);
void ns_run_spec_free(NsRunSpec *spec);

#endif
