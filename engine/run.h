/* One run of a scenario (engine/run.c and its parts): what `needlesim run`, `bench` and the live
 * session share. The scenario is loaded and built, then ticked step by step (the script, an
 * on_tick, a replayed log or a live client sets the controls), then scored and reported. */
#ifndef NS_RUN_H
#define NS_RUN_H

#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>

#include "control_log.h"
#include "coupling.h"
#include "json.h"
#include "plan_obs.h"
#include "quality_watch.h"
#include "rod.h"
#include "run_render.h"
#include "run_spec.h"
#include "run_video.h"
#include "run_warnings.h"
#include "scenario.h"
#include "series.h"
#include "tissue.h"

typedef struct NsRunOpts {
    const char *scenario, *out_dir, *record, *replay;
    /* written into a recorded log (control_log.h); --rescore: replay a log recorded against
     * another scenario file */
    const char *trainee, *session;
    bool rescore;
    bool score_row;       /* --score-row: DIR/score_row.csv for `needlesim score` (score_csv.h) */
    bool live;            /* a live session (docs/live.md): controls come given to ns_run_tick */
    const char *sets[32]; /* --set KEY=VALUE */
    int nsets;
    long steps; /* 0: the scenario decides */
    int threads;
    int solver; /* NsCoupledSolverKind */
    bool quiet;
    /* pictures (docs/rendering.md): summary.png unless --no-render; frames and video on ask */
    bool no_render, frames;
    const char *video;
    int width, height, frame_every; /* frame_every 0: the scenario's camera decides */
    int samples;          /* --samples: OpenGL samples a pixel (0: 1, edges smoothed after) */
    int views[3], nviews; /* --view / --layout (NsView); nviews 0: the scenario's */
    /* checkpoints (docs/checkpoints.md): --checkpoint-at T FILE, --resume FILE */
    const char *checkpoint, *resume;
    double checkpoint_at;
    /* --plan DIR: DIR/path.csv (`needlesim plan -o DIR`) drawn in the frames */
    const char *plan_dir;
    bool threads_given, solver_given;
} NsRunOpts;

/* What a script saw of the simulation at one tick (the `sim` table's fields) and what it set:
 * a run that writes a checkpoint keeps one per tick, so that a resumed run can bring a fresh
 * script to the same point by running it again against them (engine/run_checkpoint.c). */
typedef struct NsTickView {
    double depth, tip[3], axial, tip_dir[3], bevel_dir[3];
    int fr[3], cutting, seeds, exited, bone_contact, tip_exited, events;
    int more;      /* the script had more to do after the tick */
    NsControl ctl; /* the controls it set */
} NsTickView;

/* act.steer and ns.plan in a run (engine/run_steer.c): the obstacles as distances, the model's
 * curvature, and what the report's `steering` says. */
typedef struct NsRunSteer {
    NsPlanObs obs;
    bool have_obs; /* else obs_err says why */
    char obs_err[256];
    double kappa;           /* the model's curvature k_c tan(psi) [1/m] */
    double lo[3], hi[3];    /* the tissue's bounding box as built: the RRT's workspace [m] */
    NsSeries ms;            /* planning time per replan [ms] (measured only) */
    int replans, fallbacks; /* fallbacks: RRT replans that found no path (the helix choice) */
    double min_clear;       /* least distance from the tip to an avoided obstacle [m] */
    double kappa_estimate;  /* the curvature the last replan predicted with [1/m] */
    bool used, rrt;
    int target;    /* the steered-to target (-1: none) */
    bool *avoided; /* (obstacle_count): named in an avoid list */
    double *way;   /* (way_n x 3) the kept RRT path's waypoints [m] */
    int way_n;
    double *plan; /* (plan_n x 3) the last replan's predicted arc, every mm [m] (frames draw it) */
    int plan_n;
    int rollouts;        /* planner.rollout calls (engine/run_rollout.c) */
    long rollout_steps;  /* their steps of the world's copy, in all */
    NsSeries rollout_ms; /* wall time of each [ms] (measured only) */
} NsRunSteer;

/* The debrief (engine/run_debrief.c, docs/rendering.md "The debrief"): what a trainee is told
 * after a run. Plain sentences from the run's events (each target's error along and across the
 * insertion and how far the tissue carried it, each obstacle's closest approach or entry,
 * twists, bone, seeds, the warnings), the report's `debrief`, and a chart of the axial force
 * against depth with the events marked, on the contact sheet. */
/* What the chart marks, in step order. */
enum { NS_MARK_TWIST, NS_MARK_PUNCTURE, NS_MARK_SEED, NS_MARK_OBSTACLE, NS_MARK_BONE };

typedef struct NsRunDebrief {
    NsSeries depth, force; /* each step's depth [m] and axial force [N] (with pictures only) */
    struct NsDebriefMark {
        int kind, at; /* NS_MARK_*, index into depth and force */
    } * marks;
    int mark_n, mark_cap;
    int twists;    /* times the base began to turn */
    bool twisting; /* it turned in the last step */
    bool began;    /* ... and not in the one before */
} NsRunDebrief;

/* ---- the model ---- */

typedef struct NsRun {
    NsRunOpts opt;
    NsScenario sc;
    NsRunSpec spec;
    NsTissue tissue;
    NsRod rod;
    NsCoupled c;
    bool have_sc, have_spec, have_tissue, have_rod, have_c;
    int sim_ref, act_ref,
        co_ref; /* registry refs: `sim`, the actions module, the script's coroutine */
    /* statistics */
    NsSeries step_ms, total_ms, lcp_ms, tissue_ms, needle_ms, remesh_ms, trials, iterations;
    long steps;
    long factorizations; /* of the tissue matrix, made or adopted (schur; the paper's needs none) */
    int consistent;
    NsRunWarnings warn; /* NaN, inverted, unconverged, friction unresolved (run_warnings.h) */
    int repaired;       /* tissue nodes moved by the remesher's repair (ns_remesh_repair) */
    /* the tissue mesh's worst dihedral angle over every step, at rest and deformed
     * (min_dihedral_deg_any_step, sim/quality_watch.h) */
    NsDihedralWatch dw;
    bool have_dw;
    double max_axial, last_axial, path_cut, wall_s, last_tip[3];
    NsMesh orig; /* the tissue's mesh as built: every needle's exit restores it */
    bool have_orig;
    int exited;                   /* the current needle has been withdrawn out of the tissue */
    int needles;                  /* needles used so far */
    int last_fr[3], last_cutting; /* friction-state counts and cutting at the last step */
    int *target_hint, *marker_hint;
    /* seeds released so far: material point, time, target index (-1: nearest at the end) */
    struct Seed {
        double u[3], t;
        int target, hint;
    } * seeds;
    int seed_n, seed_cap;
    /* physical outcomes (issue 32): the tip stopped at bone, the tip out through the surface, a
     * withdrawn needle in again (re-entry) */
    struct Event {
        double t, x[3];
        int type, region; /* EVENT_*; bone: the region touched */
    } * events;
    int event_n, event_cap;
    /* obstacles: per obstacle, whether the needle entered it, when first, for how many steps,
     * where the tip was when it went in, and the deepest it got from there */
    struct Obstacle {
        bool violated, inside;
        double first_t, entry[3], max_depth;
        int steps_inside;
        double closest, closest_t; /* the tip's least distance to it and when [m, s] (debrief) */
        bool approached;           /* closest holds a distance */
    } * obst;
    int tip_hint, insertions;
    double prev_v;
    /* output */
    char *traj_tmp, *report_tmp, *rec_tmp, *row_tmp;
    FILE *rec;
    NsControlLog replay;
    bool made_dir, progress_shown, script_finished;
    char note[512];      /* a warning for stderr once the run has succeeded (the replayed log) */
    size_t made_from;    /* made_dir: the first folder made for -o is opt.out_dir[0 .. made_from) */
    bool time_capped;    /* stopped at NS_LIMIT_DEFAULT_SIM_TIME with the script still running */
    long max_steps;      /* the run's steps (0: until the script ends) */
    long time_cap;       /* steps after which an unfinished script is stopped */
    int more;            /* the control source (script or log) has more */
    bool tty;            /* progress on stderr */
    double t0;           /* the loop's start (ns_wall_s) */
    bool stop_when_done; /* bench: the script's end ends the run even before --steps */
    bool live_scripted;  /* live: the scenario's script drives still (live.script) */
    FILE *traj;
    /* pictures */
    bool rendering;
    NsRunRender rr;
    int every;          /* steps between frames */
    int *prev_tet_node; /* the tets before the latest step (what remeshing changed) */
    int prev_slots, prev_cap;
    uint8_t *changed; /* per tet slot */
    bool *obstacle_region;
    double bounds[6];
    bool entered;      /* the entry moment was taken */
    bool *reached;     /* per target: the tip-reached moment was taken */
    double peak_axial; /* the axial force's peak since the last puncture (moments) */
    int punctures;
    double end_s;     /* the run's end: last frame, contact sheet, video closed [s] */
    NsSeries tips[3]; /* bench --compare: the tip after every step [m] */
    bool log_tips;
    /* checkpoints: the views of every script tick so far (keep_views), the targets' positions
     * they showed (target_count x 3 per view), the trajectory's size after its header */
    bool keep_views, checkpointed;
    NsTickView *views;
    double *view_tx;
    long view_n, view_cap;
    long traj_start;
    FILE *resume_f; /* --resume: the checkpoint, read in two parts (header, then the rest) */
    struct NsPack *resume_pack;
    struct NsCheckpointHeader *resume_hdr;
    uint64_t ck_scenario_hash, ck_replay_hash; /* of the files as loaded (checkpoint header) */
    /* report.json: more keys at its end (a live session's `live`), or NULL */
    void (*report_extra)(NsJson *j, void *ctx);
    void *report_ctx;
    NsRunSteer steer;
    bool have_steer;
    double *prior_plan; /* (prior_plan_n x 3) --plan DIR's path [m], drawn in frames; or NULL */
    int prior_plan_n;
    struct NsRunDose *dose; /* dosimetry = {...} (engine/run_dosimetry.c), or NULL */
    NsRunCues cues;         /* the authored video's (engine/run_video.c) */
    NsRunDebrief debrief;   /* engine/run_debrief.c */
} NsRun;

enum { EVENT_BONE_CONTACT, EVENT_TIP_EXIT, EVENT_REENTRY };

typedef struct NsTargetResult {
    double x[3], error_mm, score;
    bool hit, by_seed;
} NsTargetResult;

typedef struct NsSeedResult {
    double x[3], error_mm;
    int target;
} NsSeedResult;

typedef struct NsRunResults {
    NsTargetResult *targets;
    NsSeedResult *seeds;
    double (*markers)[3];
    double target_part, obstacle_penalty, total;
    int violated;
} NsRunResults;

static inline double ns_run_dot3(const double *a, const double *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

extern const char *const ns_run_event_names[3];

/* engine/run.c: the run: building, the loop, seeds, obstacles, events */
int ns_run_record_events(NsRun *r, const NsCouplingStats *st, double t, const double tip[3]);
const char *ns_run_event_region(const NsRun *r, const struct Event *e);
const double *ns_run_tip(const NsRun *r);
double ns_run_depth(const NsRun *r);
int ns_run_world_of(const NsMesh *m, const double u[3], int *hint, double x[3]);
int ns_run_place_needle(NsRun *r, const char *what, char *err, int err_sz);
int ns_run_build(NsRun *r, char *err, int err_sz);
int ns_run_next_needle(NsRun *r, const NsEntry *e, double t, char *err, int err_sz);
int ns_run_release_seed(NsRun *r, double t, char *err, int err_sz);
void ns_run_check_obstacles(NsRun *r, double t, int exited);
/* A run after ns_run_build: begin (its length, the first frame), tick until it returns 0
 * (each tick takes one step with the given controls, or the replayed log's, or the script's;
 * 1: a step was taken, 0: the run is over, -1: an error, in err), finish (wall time, whether the
 * script finished). ns_run_loop does all three. */
int ns_run_begin(NsRun *r, char *err, int err_sz);
int ns_run_tick(NsRun *r, const NsControl *given, char *err, int err_sz);
void ns_run_finish(NsRun *r);
int ns_run_loop(NsRun *r, char *err, int err_sz);
void ns_run_free(NsRun *r);
/* engine/run_script.c: the Lua bridge (the `sim` table, the script's coroutine, on_tick) */
int ns_run_script_start(NsRun *r, char *err, int err_sz);
/* given: a live session's controls, which on_tick sees in sim.control and may change (the
 * script is not resumed unless live.script has it drive until it ends: r->live_scripted). */
int ns_run_script_tick(NsRun *r, double t, int exited, const NsControl *given, int *more,
                       NsControl *ctl, char *err, int err_sz);
int ns_run_script_replay_tick(NsRun *r, long k, char *err, int err_sz);
/* engine/run_rollout.c: planner.rollout{length, speed}, the curvature a copy of the world gives */
int ns_run_l_rollout(struct lua_State *L);
/* engine/run_steer.c: `sim.planner` (act.steer, ns.plan) and the report's `steering` */
int ns_run_steer_setup(NsRun *r, char *err, int err_sz);
void ns_run_steer_free(NsRunSteer *s);
void ns_run_steer_push(lua_State *L, NsRun *r);
void ns_run_steer_report(NsJson *j, const NsRun *r, const NsRunResults *res);
/* engine/run_checkpoint.c: checkpoints (docs/checkpoints.md) */
int ns_run_views_push(NsRun *r, const NsTickView *v, const double *tx);
/* --resume: reads the checkpoint's header and takes the run's settings from it (--set, --steps,
 * --threads, --solver; given ones must agree). Before ns_run_load. */
int ns_run_checkpoint_open(NsRun *r, char *err, int err_sz);
/* --resume, after ns_run_begin: the world, the run's state and its script brought to the
 * checkpoint's step. */
int ns_run_checkpoint_resume(NsRun *r, char *err, int err_sz);
/* --checkpoint-at: the scenario file's (and replayed log's) hash, taken right after loading. */
int ns_run_checkpoint_hash_inputs(NsRun *r, char *err, int err_sz);
/* --checkpoint-at: after each step; writes the checkpoint at the first step at or after T. */
int ns_run_checkpoint_maybe(NsRun *r, char *err, int err_sz);
void ns_run_checkpoint_free(NsRun *r);
/* engine/run_output.c: the output folder, the trajectory, the temporary files */
char *ns_run_path_join(const char *dir, const char *name);
int ns_run_outputs_prepare(NsRun *r, char *err, int err_sz);
void ns_run_traj_header(NsRun *r);
void ns_run_outputs_remove(NsRun *r);
/* engine/run_score.c: scoring the placement */
double ns_run_dist_mm(const double *a, const double *b);
int ns_run_score(NsRun *r, NsRunResults *res);
/* The score of the state now, the lookups' hints left as they were (pictures, live frames):
 * what is looked at, and how often, must not change the final score's last bits. */
int ns_run_score_peek(NsRun *r, NsRunResults *res);
void ns_run_results_free(NsRunResults *res);
/* engine/cmd_run.c: --record's path checked against the run's other files; the control logs
 * opened (a --replay read and checked, a --record started) */
int ns_run_check_record_path(const NsRunOpts *o);
/* The same for any output path the command line names (flag: its option, for the message). */
int ns_run_check_out_path(const NsRunOpts *o, const char *out, const char *flag);
/* A --set KEY=VALUE added to o: NULL, or why not (a format with one %s, the value). */
const char *ns_run_opt_set(NsRunOpts *o, const char *v);
int ns_run_open_logs(NsRun *r, char *err, int err_sz);
/* engine/run_report.c: report.json */
void ns_run_stats_object(NsJson *j, const char *key, const NsSeries *s);
void ns_run_json_vec(NsJson *j, const char *key, const double *v);
void ns_run_timing_json(NsJson *j, const NsRun *r);
int ns_run_write_report(NsRun *r, const NsRunResults *res, uint64_t hash, char *err, int err_sz);
/* engine/run_moments.c: pictures of the key moments, frames and video */
int ns_run_render_setup(NsRun *r, char *err, int err_sz);
/* --plan DIR: DIR/path.csv into r->prior_plan (plan_path_csv.h), before anything is written. */
int ns_run_prior_plan_read(NsRun *r, char *err, int err_sz);
int ns_run_render_before_step(NsRun *r);
int ns_run_render_now(NsRun *r, const char *caption, bool final, const NsRunResults *res_in,
                      char *err, int err_sz);
int ns_run_render_after_step(NsRun *r, const NsCouplingStats *st, bool dropped, char *err,
                             int err_sz);
int ns_run_render_end(NsRun *r, const NsRunResults *res, char *err, int err_sz);

/* Loads the scenario (its --set values), reads its run fields and starts its script
 * (engine/run_script.c); refuses a run that would not know when to stop. */
int ns_run_load(NsRun *r, char *err, int err_sz);
/* After the loop: the score, the last pictures, the state hash. res is filled (free it with
 * ns_run_results_free). */
int ns_run_end(NsRun *r, NsRunResults *res, uint64_t *hash, char *err, int err_sz);
/* The trajectory closed, and every output renamed into place: the report and trajectory, the
 * pictures, the control log last (a log on disk means the run and its report are there). */
int ns_run_outputs_commit(NsRun *r, char *err, int err_sz);
/* engine/run_dosimetry.c: dosimetry = {...}: the regions' voxels and the planned dose when the
 * run is built (begin), the delivered dose at its end, report.json's `dosimetry`, DIR/dvh.csv
 * (written as a part file, committed with the other outputs; uncommit removes it again). */
int ns_run_dosimetry_begin(NsRun *r, char *err, int err_sz);
int ns_run_dosimetry_end(NsRun *r, char *err, int err_sz);
void ns_run_dosimetry_json(NsJson *j, const NsRun *r);
int ns_run_dosimetry_write(NsRun *r, char *err, int err_sz);
int ns_run_dosimetry_commit(NsRun *r);
void ns_run_dosimetry_uncommit(NsRun *r);
void ns_run_dosimetry_free(NsRun *r);
/* The isodose lines (100 % and 150 % of the prescription) on a frame's cut face: sets the
 * scene input's dose callback when the run has dosimetry. */
struct NsSceneInput;
void ns_run_dosimetry_isodose(const NsRun *r, struct NsSceneInput *in);
/* The DVH of region 0 prostate, 1 urethra, 2 rectum, planned (delivered 0) or delivered; NULL
 * before the run's end or without dosimetry. */
const struct NsDvh *ns_run_dosimetry_dvh(const NsRun *r, int delivered, int region);
/* engine/run_dose_chart.c: the contact sheet's DVH chart (im zeroed without dosimetry) and its
 * table rows (returns how many of max it wrote). */
struct NsImage;
int ns_run_dosimetry_chart(const NsRun *r, struct NsImage *im, char *err, int err_sz);
int ns_run_dosimetry_rows(const NsRun *r, char (*rows)[128], int max);

/* engine/run_debrief.c (above) */
/* The shortest distance from p to tet e of m at its world positions [m] (0 inside). */
double ns_run_tet_distance(const double *x, const int *tet_node, int e, const double p[3]);

/* After a step: the twist count, and with pictures the chart's point. */
int ns_run_debrief_step(NsRun *r, double twist_rate, double depth, double axial);
/* A mark on the chart at the latest step (with pictures only). */
int ns_run_debrief_mark(NsRun *r, int kind);
/* The closest approach of the tip at p to each obstacle not entered this step (call after the
 * obstacles' check): the distance to the nearest tet of the obstacle's region. */
void ns_run_debrief_closest(NsRun *r, const double p[3], double t);

/* The sentences (at most max, each < 256 bytes) into out; returns how many. */
int ns_run_debrief_sentences(const NsRun *r, const NsRunResults *res, char (*out)[256], int max);
/* report.json's `debrief` {sentences, targets [{name, moved_mm, along_mm, across_mm}]}. */
void ns_run_debrief_report(NsJson *j, const NsRun *r, const NsRunResults *res);
/* The sentences as contact-sheet rows under "debrief:", broken to 100 columns; returns how
 * many of max it wrote. */
int ns_run_debrief_rows(const NsRun *r, const NsRunResults *res, char (*rows)[128], int max);
/* The force-depth chart (empty image without steps). */
int ns_run_debrief_chart(const NsRun *r, struct NsImage *im, char *err, int err_sz);

void ns_run_debrief_free(NsRunDebrief *d);

#endif
