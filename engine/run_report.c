/* report.json (run.h; docs/scenarios.md documents every key). */
#include <errno.h>
#include <lauxlib.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "cleanup.h"
#include "control_log.h"
#include "coupling.h"
#include "err.h"
#include "json.h"
#include "needle_path.h"
#include "ns_config.h"
#include "ns_limits.h"
#include "out_files.h"
#include "quality.h"
#include "remesh.h"
#include "rod.h"
#include "run.h"
#include "score_csv.h"

void ns_run_stats_object(NsJson *j, const char *key, const NsSeries *s)
{
    double lo, mean, hi;
    ns_series_range(s, &lo, &mean, &hi);
    ns_json_key(j, key);
    ns_json_begin_object(j);
    ns_json_key(j, "min");
    ns_json_number(j, lo);
    ns_json_key(j, "mean");
    ns_json_number(j, mean);
    ns_json_key(j, "max");
    ns_json_number(j, hi);
    ns_json_end_object(j);
}

void ns_run_json_vec(NsJson *j, const char *key, const double *v)
{
    ns_json_key(j, key);
    ns_json_begin_array(j);
    for (int k = 0; k < 3; k++)
        ns_json_number(j, v[k]);
    ns_json_end_array(j);
}

/* The step's wall time (median, mean, p95, max) and each stage's median and mean per step
 * (the paper's Table 2 columns): the means show what the medians hide, the steps that rebuild
 * many Jacobians or refactor. */
void ns_run_timing_json(NsJson *j, const NsRun *r)
{
    ns_json_key(j, "step_ms");
    ns_json_begin_object(j);
    ns_json_key(j, "median");
    ns_json_number(j, ns_series_quantile(&r->step_ms, 0.5));
    ns_json_key(j, "mean");
    ns_json_number(j, ns_series_mean(&r->step_ms));
    ns_json_key(j, "p95");
    ns_json_number(j, ns_series_quantile(&r->step_ms, 0.95));
    ns_json_key(j, "max");
    ns_json_number(j, ns_series_quantile(&r->step_ms, 1.0));
    ns_json_end_object(j);
    const NsSeries *st[5] = {&r->total_ms, &r->lcp_ms, &r->tissue_ms, &r->needle_ms, &r->remesh_ms};
    static const char *const stn[5] = {"total", "lcp", "tissue", "needle", "remesh"};
    for (int m = 0; m < 2; m++) {
        ns_json_key(j, m ? "stages_mean_ms" : "stages_ms");
        ns_json_begin_object(j);
        for (int k = 0; k < 5; k++) {
            ns_json_key(j, stn[k]);
            ns_json_number(j, m ? ns_series_mean(st[k]) : ns_series_quantile(st[k], 0.5));
        }
        ns_json_end_object(j);
    }
}

/* report.json: the run: scenario, version, solver and its settings, the --set values, its length.
 */
static void report_header(NsJson *j, NsRun *r)
{
    ns_json_key(j, "schema");
    ns_json_string(j, "needlesim-report/1");
    ns_json_key(j, "scenario");
    ns_json_string(j, r->sc.name);
    ns_json_key(j, "scenario_file");
    ns_json_string(j, r->sc.path);
    ns_json_key(j, "version");
    ns_json_string(j, NS_VERSION);
    ns_json_key(j, "solver");
    ns_json_string(j, ns_coupled_solver_name((NsCoupledSolverKind)r->opt.solver));
    ns_json_key(j, "threads");
    ns_json_int(j, r->opt.threads);
    ns_json_key(j, "solver_settings"); /* what the step ran with (the scenario's solver = {}) */
    ns_json_begin_object(j);
    ns_json_key(j, "tolerance");
    ns_json_number(j, r->c.params.tau_sol);
    ns_json_key(j, "check_tolerance");
    ns_json_number(j, r->c.params.tau_check);
    ns_json_key(j, "lazy_threshold");
    ns_json_number(j, r->tissue.params.lazy_threshold);
    ns_json_key(j, "tip_block");
    ns_json_bool(j, r->c.params.tip_block != 0);
    ns_json_end_object(j);
    if (r->spec.accuracy > 0.0) { /* the scenario's accuracy = ... (docs/performance.md) */
        ns_json_key(j, "accuracy");
        ns_json_begin_object(j);
        ns_json_key(j, "tip_m");
        ns_json_number(j, r->spec.accuracy);
        ns_json_key(j, "front");
        ns_json_string(j, r->spec.accuracy_front);
        ns_json_key(j, "chosen");
        ns_json_string(j, r->spec.accuracy_label);
        ns_json_key(j, "dt_s");
        ns_json_number(j, r->spec.dt);
        ns_json_key(j, "measured_tip_error_m");
        ns_json_number(j, r->spec.accuracy_tip_error);
        ns_json_key(j, "measured_cost_ms_per_s");
        ns_json_number(j, r->spec.accuracy_cost);
        ns_json_end_object(j);
    }
    ns_json_key(j, "sets");
    ns_json_begin_array(j);
    for (int i = 0; i < r->opt.nsets; i++)
        ns_json_string(j, r->opt.sets[i]);
    ns_json_end_array(j);
    ns_json_key(j, "replayed_from");
    ns_json_string(j, r->opt.replay ? r->opt.replay : "");
    ns_json_key(j, "steps");
    ns_json_int(j, r->steps);
    ns_json_key(j, "script_finished");
    ns_json_bool(j, r->script_finished);
    ns_json_key(j, "time_limit_s"); /* > 0: the script was stopped at this simulated time */
    ns_json_number(j, r->time_capped ? NS_LIMIT_DEFAULT_SIM_TIME : 0.0);
    ns_json_key(j, "dt_s");
    ns_json_number(j, r->spec.dt);
    ns_json_key(j, "sim_time_s");
    ns_json_number(j, (double)r->steps * r->spec.dt);
    ns_json_key(j, "wall_time_s");
    ns_json_number(j, r->wall_s);
}

/* report.json: the step's timings (the paper's Tables 2 and 3) and the mesh. */
static void report_solver(NsJson *j, NsRun *r)
{
    ns_run_timing_json(j, r);
    ns_run_stats_object(j, "lcp_trials", &r->trials);
    ns_run_stats_object(j, "cg_iterations", &r->iterations);
    ns_json_key(j, "factorizations");
    ns_json_int(j, r->factorizations);
    ns_json_key(j, "friction_consistent_fraction");
    ns_json_number(j, r->steps ? (double)r->consistent / (double)r->steps : 1.0);
    const NsMesh *M = &r->tissue.mesh;
    NsQualityStats q;
    ns_mesh_quality(M, false, &q);
    ns_json_key(j, "mesh");
    ns_json_begin_object(j);
    ns_json_key(j, "tets");
    ns_json_int(j, M->tet_alive);
    ns_json_key(j, "nodes");
    ns_json_int(j, M->node_alive);
    ns_json_key(j, "min_dihedral_deg");
    ns_json_number(j, q.min_dihedral_deg);
    ns_json_key(j, "max_dihedral_deg");
    ns_json_number(j, q.max_dihedral_deg);
    ns_json_key(j, "remesh_repaired_nodes");
    ns_json_int(j, r->repaired);
    /* The worst dihedral angle over every step of the run (sim/quality_watch.h): at rest, the
     * remesher's quality (§3.4.1), and in the deformed tissue. */
    ns_json_key(j, "min_dihedral_deg_any_step");
    ns_json_number(j, r->dw.min_rest_deg);
    ns_json_key(j, "min_dihedral_deg_any_step_deformed");
    ns_json_number(j, r->dw.min_world_deg);
    ns_json_key(j, "tissue_energy_j"); /* kinetic + elastic, at the end */
    ns_json_number(j, ns_tissue_energy(&r->tissue));
    ns_json_end_object(j);
}

/* report.json: the needle, the targets and the seeds. */
static void report_placement(NsJson *j, NsRun *r, const NsRunResults *res)
{
    ns_json_key(j, "needle");
    ns_json_begin_object(j);
    ns_json_key(j, "kind");
    ns_json_string(j, r->spec.needle_kind);
    ns_json_key(j, "tip_m");
    ns_json_begin_array(j);
    for (int k = 0; k < 3; k++)
        ns_json_number(j, ns_run_tip(r)[k]);
    ns_json_end_array(j);
    ns_json_key(j, "depth_m");
    ns_json_number(j, ns_run_depth(r));
    ns_json_key(j, "max_axial_force_n");
    ns_json_number(j, r->max_axial);
    ns_json_key(j, "path_cut_m");
    ns_json_number(j, r->path_cut);
    ns_json_end_object(j);
    ns_json_key(j, "targets");
    ns_json_begin_array(j);
    for (int i = 0; i < r->spec.target_count; i++) {
        const NsRunTarget *t = &r->spec.targets[i];
        const NsTargetResult *tr = &res->targets[i];
        ns_json_begin_object(j);
        ns_json_key(j, "name");
        ns_json_string(j, t->name);
        ns_json_key(j, "error_mm");
        ns_json_number(j, tr->error_mm);
        ns_json_key(j, "tolerance_mm");
        ns_json_number(j, 1e3 * t->tolerance);
        ns_json_key(j, "hit");
        ns_json_bool(j, tr->hit);
        ns_json_key(j, "by");
        ns_json_string(j, tr->by_seed ? "seed" : "tip");
        ns_run_json_vec(j, "position_m", tr->x);
        ns_json_end_object(j);
    }
    ns_json_end_array(j);
    ns_json_key(j, "seeds");
    ns_json_begin_array(j);
    for (int k = 0; k < r->seed_n; k++) {
        const NsSeedResult *sd = &res->seeds[k];
        ns_json_begin_object(j);
        ns_json_key(j, "target");
        ns_json_string(j, sd->target >= 0 ? r->spec.targets[sd->target].name : "");
        ns_json_key(j, "error_mm");
        ns_json_number(j, sd->error_mm);
        ns_json_key(j, "released_s");
        ns_json_number(j, r->seeds[k].t);
        ns_run_json_vec(j, "position_m", sd->x);
        ns_json_end_object(j);
    }
    ns_json_end_array(j);
    ns_json_key(j, "seeds_planned");
    ns_json_int(j, r->spec.seed_count);
}

/* report.json: obstacles and markers. */
static void report_tissue(NsJson *j, NsRun *r, const NsRunResults *res)
{
    ns_json_key(j, "obstacles");
    ns_json_begin_array(j);
    for (int k = 0; k < r->spec.obstacle_count; k++) {
        const struct Obstacle *o = &r->obst[k];
        ns_json_begin_object(j);
        ns_json_key(j, "name");
        ns_json_string(j, r->spec.obstacles[k].name);
        ns_json_key(j, "region");
        ns_json_string(j, r->sc.regions[r->spec.obstacles[k].region].name);
        ns_json_key(j, "violated");
        ns_json_bool(j, o->violated);
        ns_json_key(j, "max_depth_mm");
        ns_json_number(j, 1e3 * o->max_depth);
        ns_json_key(j, "first_s");
        ns_json_number(j, o->violated ? o->first_t : 0.0);
        ns_json_key(j, "steps_inside");
        ns_json_int(j, o->steps_inside);
        if (o->approached) { /* the tip's least distance to the region (run_debrief.c) */
            ns_json_key(j, "closest_mm");
            ns_json_number(j, 1e3 * o->closest);
            ns_json_key(j, "closest_s");
            ns_json_number(j, o->closest_t);
        }
        ns_json_end_object(j);
    }
    ns_json_end_array(j);
    ns_json_key(j, "markers");
    ns_json_begin_array(j);
    for (int i = 0; i < r->spec.marker_count; i++) {
        ns_json_begin_object(j);
        ns_json_key(j, "name");
        ns_json_string(j, r->spec.markers[i].name);
        ns_run_json_vec(j, "position_m", res->markers[i]);
        ns_json_key(j, "displacement_mm");
        ns_json_number(j, ns_run_dist_mm(res->markers[i], r->spec.markers[i].at));
        ns_json_end_object(j);
    }
    ns_json_end_array(j);
}

/* report.json: the score, the events at the tip and the warnings. */
static void report_outcome(NsJson *j, NsRun *r, const NsRunResults *res)
{
    ns_json_key(j, "score");
    ns_json_begin_object(j);
    ns_json_key(j, "formula");
    ns_json_string(j, "needlesim-score/1");
    ns_json_key(j, "total");
    ns_json_number(j, res->total);
    ns_json_key(j, "targets");
    ns_json_number(j, res->target_part);
    ns_json_key(j, "obstacle_penalty");
    ns_json_number(j, res->obstacle_penalty);
    ns_json_key(j, "obstacles_violated");
    ns_json_int(j, res->violated);
    ns_json_key(j, "insertions");
    ns_json_int(j, r->insertions);
    ns_json_key(j, "path_cut_mm");
    ns_json_number(j, 1e3 * r->path_cut);
    ns_json_key(j, "peak_axial_force_n");
    ns_json_number(j, r->max_axial);
    ns_json_key(j, "duration_s");
    ns_json_number(j, (double)r->steps * r->spec.dt);
    ns_json_end_object(j);
    ns_json_key(j, "events");
    ns_json_begin_array(j);
    for (int i = 0; i < r->event_n; i++) {
        const struct Event *e = &r->events[i];
        ns_json_begin_object(j);
        ns_json_key(j, "t_s");
        ns_json_number(j, e->t);
        ns_json_key(j, "type");
        ns_json_string(j, ns_run_event_names[e->type]);
        ns_json_key(j, "tip_m");
        ns_json_begin_array(j);
        for (int k = 0; k < 3; k++)
            ns_json_number(j, e->x[k]);
        ns_json_end_array(j);
        if (e->type == EVENT_BONE_CONTACT) {
            ns_json_key(j, "region");
            ns_json_string(j, ns_run_event_region(r, e));
        }
        ns_json_end_object(j);
    }
    ns_json_end_array(j);
    /* a needle's tip stopped by bone on its way in: in a brachytherapy implant, pubic arch
     * interference (the trainee re-aims) */
    int bone = 0;
    for (int i = 0; i < r->event_n; i++)
        bone += r->events[i].type == EVENT_BONE_CONTACT;
    ns_json_key(j, "bone_interferences");
    ns_json_int(j, bone);
    ns_run_debrief_report(j, r, res);
    ns_json_key(j, "warnings");
    ns_json_begin_object(j);
    ns_json_key(j, "nan");
    ns_json_int(j, r->warn.total[NS_WARN_NAN]);
    ns_json_key(j, "inverted");
    ns_json_int(j, r->warn.total[NS_WARN_INVERTED]);
    ns_json_key(j, "unconverged");
    ns_json_int(j, r->warn.total[NS_WARN_UNCONVERGED]);
    ns_json_key(j, "lcp_unresolved");
    ns_json_int(j, r->warn.total[NS_WARN_LCP]);
    ns_json_end_object(j);
    ns_run_warnings_report(j, &r->warn);
}

/* report.json: the pictures (docs/rendering.md). */
static void report_render(NsJson *j, NsRun *r)
{
    ns_json_key(j, "render");
    ns_json_begin_object(j);
    ns_json_key(j, "enabled");
    ns_json_bool(j, r->rendering);
    if (r->rendering) {
        double rm, em;
        ns_run_render_medians(&r->rr, &rm, &em);
        ns_json_key(j, "info");
        ns_json_string(j, ns_renderer_info(r->rr.frame.gl));
        ns_json_key(j, "width");
        ns_json_int(j, r->rr.o.width);
        ns_json_key(j, "height");
        ns_json_int(j, r->rr.o.height);
        ns_json_key(j, "frames");
        ns_json_int(j, r->rr.frame_count);
        ns_json_key(j, "frame_every");
        ns_json_int(j, r->every);
        ns_json_key(j, "fps");
        ns_json_number(j, r->rr.o.fps);
        ns_json_key(j, "video");
        ns_json_string(j, r->opt.video ? r->opt.video : "");
        ns_json_key(j, "moments");
        ns_json_int(j, r->rr.moment_count);
        ns_json_key(j, "render_ms_median");
        ns_json_number(j, rm);
        ns_json_key(j, "encode_ms_median");
        ns_json_number(j, em);
        ns_json_key(j, "ffmpeg_cpu_ms_per_frame");
        ns_json_number(j, r->opt.video && r->rr.frame_count
                              ? 1e3 * r->rr.ffmpeg_cpu_s / (double)r->rr.frame_count
                              : 0.0);
        ns_json_key(j, "render_s");
        ns_json_number(j, r->rr.render_s);
        ns_json_key(j, "share_of_wall");
        ns_json_number(j, r->rr.render_s / fmax(r->wall_s + r->end_s, 1e-9));
    }
    ns_json_end_object(j);
}

/* Appends name to list (size n), ';' and '=' in it as '_' unless it is the separator itself. */
static void append_item(char *list, size_t n, const char *name)
{
    size_t at = strlen(list);
    bool sep = strcmp(name, ";") == 0;
    for (; *name && at + 1 < n; name++)
        list[at++] = !sep && (*name == ';' || *name == '=') ? '_' : *name;
    list[at] = '\0';
}

/* --score-row: DIR/score_row.csv, the replay's part of its row in scores.csv (score_csv.h). */
static int write_score_row(NsRun *r, const NsRunResults *res, uint64_t hash, char *err, int err_sz)
{
    r->row_tmp = ns_run_path_join(r->opt.out_dir, ".score_row.csv.part");
    FILE *f = r->row_tmp ? ns_out_create_part(r->row_tmp, "the score row", err, err_sz) : NULL;
    if (!f) {
        if (!r->row_tmp)
            ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    fputs(NS_SCORE_RUN_HEADER "\n", f);
    ns_csv_field(f, r->sc.name);
    int hit = 0;
    double worst = 0.0;
    for (int i = 0; i < r->spec.target_count; i++) {
        hit += res->targets[i].hit;
        worst = fmax(worst, res->targets[i].error_mm);
    }
    fprintf(f, ",%.4f,%d,%d,", res->total, r->spec.target_count, hit);
    if (r->spec.target_count)
        fprintf(f, "%.4f", worst);
    /* target_errors_mm: "name=error;..."; obstacles_entered: "name;..." (names' ';' and '=' as
     * '_') */
    char list[2048] = "", obst[2048] = "";
    for (int i = 0; i < r->spec.target_count; i++) {
        if (i)
            append_item(list, sizeof list, ";");
        append_item(list, sizeof list, r->spec.targets[i].name);
        char e[40];
        snprintf(e, sizeof e, "=%.4f", res->targets[i].error_mm);
        size_t n = strlen(list);
        snprintf(list + n, sizeof list - n, "%s", e);
    }
    for (int k = 0; k < r->spec.obstacle_count; k++)
        if (r->obst[k].violated) {
            if (obst[0])
                append_item(obst, sizeof obst, ";");
            append_item(obst, sizeof obst, r->spec.obstacles[k].name);
        }
    fputc(',', f);
    ns_csv_field(f, list);
    fprintf(f, ",%d,", res->violated);
    ns_csv_field(f, obst);
    fprintf(f, ",%.6g,%ld,%d,%d,%d,%d,%016llx\n", (double)r->steps * r->spec.dt, r->steps,
            r->warn.total[NS_WARN_NAN], r->warn.total[NS_WARN_INVERTED],
            r->warn.total[NS_WARN_UNCONVERGED], r->warn.total[NS_WARN_LCP],
            (unsigned long long)hash);
    if (fclose(f) != 0) {
        ns_set_err(err, err_sz, "cannot write '%s': %s", r->row_tmp, strerror(errno));
        return -1;
    }
    return 0;
}

int ns_run_write_report(NsRun *r, const NsRunResults *res, uint64_t hash, char *err, int err_sz)
{
    if (r->opt.score_row && write_score_row(r, res, hash, err, err_sz))
        return -1;
    FILE *f = ns_out_create_part(r->report_tmp, "the report", err, err_sz);
    if (!f)
        return -1;
    NsJson j;
    ns_json_init(&j, f, 2);
    ns_json_begin_object(&j);
    report_header(&j, r);
    report_solver(&j, r);
    report_placement(&j, r, res);
    report_tissue(&j, r, res);
    report_outcome(&j, r, res);
    char h[32];
    snprintf(h, sizeof h, "%016llx", (unsigned long long)hash);
    report_render(&j, r);
    ns_run_steer_report(&j, r, res);
    ns_run_dosimetry_json(&j, r);
    if (r->report_extra)
        r->report_extra(&j, r->report_ctx);
    ns_json_key(&j, "state_hash");
    ns_json_string(&j, h);
    ns_json_end_object(&j);
    fputc('\n', f);
    if (fclose(f) != 0) {
        ns_set_err(err, err_sz, "cannot write '%s': %s", r->report_tmp, strerror(errno));
        return -1;
    }
    return ns_run_dosimetry_write(r, err, err_sz);
}
