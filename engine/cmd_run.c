/* needlesim run SCENARIO.lua [-o DIR] [--steps N] [--threads N] [--solver NAME]
 *                            [--set KEY=VALUE]... [--record LOG | --replay LOG] [--quiet]
 *                            [--trainee ID] [--session ID] [--rescore]
 * needlesim bench SCENARIO.lua [--steps N] [--solver NAME] [--threads N] [--json]
 *
 * The run loop (DESIGN.md "Command line"): the scenario's tissue and needle are built, the
 * needle punctures the tissue's surface at the scenario's entry (skin entry), and every tick the
 * scenario's script (scripts/needlesim/actions.lua, on a coroutine) and its on_tick, or a
 * replayed control log, set the needle's controls; seeds are released, the coupled solver steps
 * (paper Algorithm 1 with remeshing at the tip, Algorithm 2), obstacles are checked and the
 * trajectory is logged. At the end the targets (material points, so they move with the tissue)
 * are scored against their seeds or the needle tip, and DIR/report.json and
 * DIR/trajectory.csv are written (docs/scenarios.md documents both). A failed run writes
 * neither: both are written to temporary names and renamed only when the run succeeded.
 * `bench` runs the same loop for a number of steps and prints the stage timings (with
 * --compare paper, both solvers'). Pictures: engine/run_render.c. */
#include "commands.h"
#include <errno.h>
#include <limits.h>
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
#include "names.h"
#include "needle_path.h"
#include "ns_config.h"
#include "ns_limits.h"
#include "out_files.h"
#include "quality.h"
#include "remesh.h"
#include "rod.h"
#include "run.h"
#include "run_render.h"
#include "run_spec.h"
#include "scenario.h"
#include "tissue.h"

static const char run_usage[] =
    "usage: needlesim run SCENARIO.lua [-o DIR] [--steps N] [--threads N] [--solver NAME]\n"
    "                     [--set KEY=VALUE]... [--record LOG.csv | --replay LOG.csv]\n"
    "                     [--trainee ID] [--session ID] [--rescore] [--score-row]\n"
    "                     [--no-render] [--frames] [--video FILE.mp4] [--width W]\n"
    "                     [--height H] [--frame-every K] [--view NAME | --layout A,B]\n"
    "                     [--samples N] [--plan DIR]\n"
    "                     [--quiet]\n"
    "                     [--checkpoint-at T FILE] [--resume FILE]\n";

/* A bad command line: one line, the usage on --help (the one-line contract for bad input). */
static int usage_error(const char *fmt, const char *arg)
{
    char shown[200], line[600];
    snprintf(shown, sizeof shown, "%s", arg);
    snprintf(line, sizeof line, fmt, shown);
    ns_one_line(line);
    fprintf(stderr, "needlesim run: %s (needlesim run --help)\n", line);
    return 2;
}

/* --view NAME, --layout A,B[,C]: the views (render/scene.h) in o. Returns 0 or 2. */
static int parse_views(NsRunOpts *o, const char *a, const char *v)
{
    if (!v)
        return usage_error("%s needs a value", a);
    if (o->nviews)
        return usage_error("%s: one --view or --layout only", a);
    char names[128];
    snprintf(names, sizeof names, "%s", v);
    bool one = strcmp(a, "--view") == 0;
    for (char *save = NULL, *t = strtok_r(names, ",", &save); t; t = strtok_r(NULL, ",", &save)) {
        int view = ns_view_parse(t);
        if (view < 0)
            return usage_error("'%s': a view is one of side, top, axis, cutaway3d, trus", t);
        if (o->nviews == (one ? 1 : 3))
            return usage_error(one ? "--view '%s': one view (--layout A,B for more)"
                                   : "--layout '%s': at most three views",
                               v);
        o->views[o->nviews++] = view;
    }
    if (o->nviews == 0 || strlen(v) >= sizeof names)
        return usage_error("'%s': expected view names", v);
    return 0;
}

const char *ns_run_opt_set(NsRunOpts *o, const char *v)
{
    const char *eq = strchr(v, '=');
    if (!eq || eq == v)
        return "--set '%s': expected KEY=VALUE";
    for (const char *c = v; *c; c++)
        if ((unsigned char)*c < 0x20 || *c == 0x7f)
            return "--set '%s': control characters are not allowed";
    if (o->nsets == 32)
        return "--set '%s': at most 32 --set values";
    for (int k = 0; k < o->nsets; k++)
        if (strncmp(o->sets[k], v, (size_t)(eq - v) + 1) == 0)
            return "--set: '%s' is given twice";
    o->sets[o->nsets++] = v;
    return NULL;
}

static int parse_args(int argc, char **argv, NsRunOpts *o)
{
    o->out_dir = "needlesim-out";
    o->threads = 1;
    o->solver = NS_COUPLED_SCHUR;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            fputs(run_usage, stdout);
            return 1;
        } else if (strcmp(a, "-o") == 0 || strcmp(a, "--steps") == 0 ||
                   strcmp(a, "--threads") == 0 || strcmp(a, "--solver") == 0 ||
                   strcmp(a, "--record") == 0 || strcmp(a, "--replay") == 0 ||
                   strcmp(a, "--set") == 0 || strcmp(a, "--trainee") == 0 ||
                   strcmp(a, "--session") == 0 || strcmp(a, "--plan") == 0) {
            if (!v)
                return usage_error("%s needs a value", a);
            i++;
            char *end;
            if (!v[0])
                return usage_error("%s: expected a path, got an empty string", a);
            if (strcmp(a, "-o") == 0) {
                o->out_dir = v;
            } else if (strcmp(a, "--plan") == 0) {
                o->plan_dir = v;
            } else if (strcmp(a, "--set") == 0) {
                const char *why = ns_run_opt_set(o, v);
                if (why)
                    return usage_error(why, v);
            } else if (strcmp(a, "--record") == 0) {
                o->record = v;
            } else if (strcmp(a, "--replay") == 0) {
                o->replay = v;
            } else if (strcmp(a, "--trainee") == 0 || strcmp(a, "--session") == 0) {
                if (!ns_control_log_id_ok(v))
                    return usage_error(a[2] == 't' ? "--trainee '%s': 1 to 64 characters of "
                                                     "A-Z a-z 0-9 . _ - only"
                                                   : "--session '%s': 1 to 64 characters of "
                                                     "A-Z a-z 0-9 . _ - only",
                                       v);
                *(a[2] == 't' ? &o->trainee : &o->session) = v;
            } else if (strcmp(a, "--solver") == 0) {
                o->solver = ns_coupled_solver_parse(v);
                o->solver_given = true;
                if (o->solver < 0)
                    return usage_error("--solver '%s': unknown solver (schur or paper)", v);
            } else {
                long n = strtol(v, &end, 10);
                if (*end || n < 1 || n > (strcmp(a, "--threads") == 0 ? 64 : NS_LIMIT_STEPS))
                    return usage_error("%s: expected a positive integer", a);
                if (strcmp(a, "--steps") == 0)
                    o->steps = n;
                else
                    o->threads = (int)n, o->threads_given = true;
            }
        } else if (strcmp(a, "--video") == 0) {
            if (!v)
                return usage_error("%s needs a value", a);
            size_t n = strlen(v);
            if (n < 5 || strcasecmp(v + n - 4, ".mp4") != 0 || v[n - 5] == '/')
                return usage_error("--video '%s': expected a FILE.mp4 path", v);
            o->video = v;
            i++;
        } else if (strcmp(a, "--width") == 0 || strcmp(a, "--height") == 0 ||
                   strcmp(a, "--frame-every") == 0) {
            if (!v)
                return usage_error("%s needs a value", a);
            char *end;
            long n = strtol(v, &end, 10);
            bool every = strcmp(a, "--frame-every") == 0;
            if (*end || (every ? (n < 1 || n > 1000000) : (n < 16 || n > 8192 || n % 2)))
                return usage_error(every ? "%s: expected a positive integer"
                                         : "%s: expected an even number of pixels in 16..8192",
                                   a);
            if (every)
                o->frame_every = (int)n;
            else if (a[2] == 'w')
                o->width = (int)n;
            else
                o->height = (int)n;
            i++;
        } else if (strcmp(a, "--samples") == 0) {
            char *end;
            long n = v ? strtol(v, &end, 10) : 0;
            if (!v || *end || n < 1 || n > 16)
                return usage_error("%s: expected a number of samples a pixel in 1..16", a);
            o->samples = (int)n;
            i++;
        } else if (strcmp(a, "--view") == 0 || strcmp(a, "--layout") == 0) {
            int rc = parse_views(o, a, v);
            if (rc)
                return rc;
            i++;
        } else if (strcmp(a, "--checkpoint-at") == 0) {
            if (!v || i + 2 >= argc)
                return usage_error("%s needs a time [s] and a file", a);
            char *end;
            double t = strtod(v, &end);
            if (*end || !(t > 0.0) || !(t <= NS_LIMIT_SIM_TIME_MAX))
                return usage_error("--checkpoint-at '%s': expected a time in seconds, > 0", v);
            if (!argv[i + 2][0] || argv[i + 2][0] == '-')
                return usage_error("--checkpoint-at T FILE: expected a file, got '%s'",
                                   argv[i + 2]);
            o->checkpoint_at = t;
            o->checkpoint = argv[i + 2];
            i += 2;
        } else if (strcmp(a, "--resume") == 0) {
            if (!v || !v[0])
                return usage_error("%s needs a checkpoint file", a);
            o->resume = v;
            i++;
        } else if (strcmp(a, "--frames") == 0) {
            o->frames = true;
        } else if (strcmp(a, "--no-render") == 0) {
            o->no_render = true;
        } else if (strcmp(a, "--quiet") == 0) {
            o->quiet = true;
        } else if (strcmp(a, "--rescore") == 0) {
            o->rescore = true;
        } else if (strcmp(a, "--score-row") == 0) {
            o->score_row = true;
        } else if (a[0] == '-' && a[1] != '\0') {
            return usage_error("unknown option '%s'", a);
        } else if (!o->scenario) {
            o->scenario = a;
        } else {
            return usage_error("one scenario only (got '%s' too)", a);
        }
    }
    if (!o->scenario)
        return usage_error("%s", "missing SCENARIO.lua");
    if (o->rescore && !o->replay)
        return usage_error("%s", "--rescore without --replay LOG.csv");
    if (o->record && o->replay && strcmp(o->record, o->replay) == 0)
        return usage_error("--record and --replay name the same file '%s'", o->record);
    if (o->checkpoint && o->resume && strcmp(o->checkpoint, o->resume) == 0)
        return usage_error("--checkpoint-at and --resume name the same file '%s'", o->checkpoint);
    if (o->no_render && (o->frames || o->video))
        return usage_error("%s", "--no-render with --frames or --video: which is it?");
    if (o->no_render && o->plan_dir)
        return usage_error("%s", "--no-render with --plan: the plan is drawn in the frames");
    if (o->no_render && (o->width || o->height || o->frame_every || o->nviews || o->samples))
        return usage_error("%s", "--no-render with --width, --height, --frame-every, --samples "
                                 "or a view");
    o->width = o->width ? o->width : 1280;
    o->height = o->height ? o->height : 720;
    return 0;
}

/* The control logs: a --replay log read and checked against this scenario (its file's hash,
 * the --set values), a --record log opened with the run's provenance (control_log.h). */
int ns_run_open_logs(NsRun *r, char *err, int err_sz)
{
    int rc = 0;
    /* The scenario file's identity, which a log carries and a replay checks (control_log.h). */
    uint64_t sc_hash = 0;
    if (rc == 0 && (r->opt.replay || r->opt.record))
        rc = ns_file_hash(r->opt.scenario, NS_LIMIT_SCRIPT_FILE_BYTES, "scenario file", &sc_hash,
                          err, err_sz);
    if (rc == 0 && r->opt.replay)
        rc = ns_control_log_read(r->opt.replay, r->spec.dt, &r->replay, err, err_sz);
    if (rc == 0 && r->opt.replay && r->replay.has_model) { /* a live session's own dt (#model) */
        const NsLogModel *m = &r->replay.model;
        NsRunCamera *cam = &r->spec.camera; /* the default frame rate in simulated time kept */
        if (cam->frame_every == (int)fmax(1.0, floor(1.0 / (cam->fps * r->spec.dt) + 0.5)))
            cam->frame_every = (int)fmax(1.0, floor(1.0 / (cam->fps * m->dt) + 0.5));
        r->spec.dt = m->dt;
        r->spec.tolerance = m->tolerance;
        r->spec.check_tolerance = m->check_tolerance;
        r->spec.lazy_threshold = m->lazy_threshold;
        r->spec.model_chosen = true;
    }
    if (rc == 0 && r->opt.replay)
        rc = ns_control_log_check_scenario(&r->replay, r->opt.replay, r->sc.name, sc_hash,
                                           NS_VERSION, r->opt.rescore, r->note, (int)sizeof r->note,
                                           err, err_sz);
    if (rc == 0 && r->opt.replay) { /* the same --set values as the recording */
        bool same = r->replay.nsets == r->opt.nsets;
        for (int i = 0; same && i < r->opt.nsets; i++) {
            bool found = false;
            for (int k = 0; k < r->replay.nsets && !found; k++)
                found = strcmp(r->replay.sets[k], r->opt.sets[i]) == 0;
            same = found;
        }
        if (!same) {
            char rec[512] = "", now[512] = "";
            for (int k = 0; k < r->replay.nsets; k++)
                snprintf(rec + strlen(rec), sizeof rec - strlen(rec), " --set %s",
                         r->replay.sets[k]);
            for (int i = 0; i < r->opt.nsets; i++)
                snprintf(now + strlen(now), sizeof now - strlen(now), " --set %s", r->opt.sets[i]);
            ns_set_err(err, err_sz,
                       "%s: the log was recorded with%s, this replay has%s: give the same --set "
                       "values",
                       r->opt.replay, rec[0] ? rec : " no --set", now[0] ? now : " none");
            rc = -1;
        }
    }
    if (rc == 0 && r->opt.record) {
        size_t n = strlen(r->opt.record) + 6;
        r->rec_tmp = malloc(n);
        if (r->rec_tmp)
            snprintf(r->rec_tmp, n, "%s.part", r->opt.record);
        r->rec = r->rec_tmp ? ns_out_create_part(r->rec_tmp, "the control log", err, err_sz) : NULL;
        if (!r->rec) {
            if (!r->rec_tmp)
                ns_set_err(err, err_sz, "out of memory");
            rc = -1;
        } else {
            NsLogModel m = {r->spec.dt, r->spec.tolerance, r->spec.check_tolerance,
                            r->spec.lazy_threshold};
            NsLogProvenance prov = {NS_VERSION,
                                    r->sc.name,
                                    sc_hash,
                                    r->opt.trainee,
                                    r->opt.session,
                                    r->opt.live,
                                    r->spec.model_chosen ? &m : NULL};
            ns_control_log_write_header(r->rec, &prov, r->opt.sets, r->opt.nsets);
        }
    }
    return rc;
}

/* The run's summary on stdout. */
static void print_summary(NsRun *r, const NsRunResults *res, uint64_t hash)
{
    printf("%s: %ld steps of %.4g s (%.3g s simulated) in %.2f s wall; median step %.2f ms\n",
           r->sc.name, r->steps, r->spec.dt, (double)r->steps * r->spec.dt, r->wall_s,
           ns_series_quantile(&r->step_ms, 0.5));
    printf("needle tip at (%.2f, %.2f, %.2f) mm, depth %.2f mm, peak axial force %.3f N\n",
           1e3 * ns_run_tip(r)[0], 1e3 * ns_run_tip(r)[1], 1e3 * ns_run_tip(r)[2],
           1e3 * ns_run_depth(r), r->max_axial);
    if (r->spec.target_count)
        printf("%-20s %10s %10s %5s %5s\n", "target", "error mm", "tol mm", "by", "hit");
    for (int i = 0; i < r->spec.target_count; i++)
        printf("%-20s %10.2f %10.2f %5s %5s\n", r->spec.targets[i].name, res->targets[i].error_mm,
               1e3 * r->spec.targets[i].tolerance, res->targets[i].by_seed ? "seed" : "tip",
               res->targets[i].hit ? "yes" : "no");
    if (r->spec.seed_count || r->seed_n)
        printf("seeds released %d of %d planned\n", r->seed_n, r->spec.seed_count);
    for (int k = 0; k < r->spec.obstacle_count; k++)
        if (r->obst[k].violated)
            printf("obstacle %s entered at t = %.2f s, %.1f mm deep\n", r->spec.obstacles[k].name,
                   r->obst[k].first_t, 1e3 * r->obst[k].max_depth);
    char warned[256];
    ns_run_warnings_line(&r->warn, warned, sizeof warned);
    printf("score %.1f / 100 (targets %.1f, obstacles -%.0f); insertions %d; %s\n", res->total,
           res->target_part, res->obstacle_penalty, r->insertions, warned);
    printf("wrote %s/report.json and %s/trajectory.csv (state hash %016llx)\n", r->opt.out_dir,
           r->opt.out_dir, (unsigned long long)hash);
    if (r->rendering) {
        double rm, em;
        ns_run_render_medians(&r->rr, &rm, &em);
        printf("wrote %s/summary.png (%d moments)", r->opt.out_dir, r->rr.moment_count);
        if (r->opt.frames)
            printf(", %s/frames/ (%ld frames)", r->opt.out_dir, r->rr.frame_count);
        if (r->opt.video)
            printf(", %s (%ld frames at %g fps)", r->opt.video, r->rr.frame_count, r->rr.o.fps);
        printf("\n");
        if (r->rr.frame_count)
            printf("rendering: %.1f ms a frame, writing %.1f ms (medians); %.0f %% of the "
                   "run's wall time",
                   rm, em, 100.0 * r->rr.render_s / fmax(r->wall_s + r->end_s, 1e-9));
        if (r->rr.frame_count && r->opt.video)
            printf("; ffmpeg's encoding %.1f ms of CPU a frame (beside the run)",
                   1e3 * r->rr.ffmpeg_cpu_s / (double)r->rr.frame_count);
        if (r->rr.frame_count)
            printf("\n");
    }
}

/* The canonical path of p's folder joined with its last component (p need not exist; its
 * folder must). Returns 0, or -1 when the folder cannot be resolved. */
static int canonical(const char *p, char *out, size_t n)
{
    char dir[PATH_MAX], real[PATH_MAX];
    const char *slash = strrchr(p, '/');
    const char *base = slash ? slash + 1 : p;
    if (slash)
        snprintf(dir, sizeof dir, "%.*s", (int)(slash - p == 0 ? 1 : slash - p), p);
    else
        snprintf(dir, sizeof dir, ".");
    if (!realpath(dir, real))
        return -1;
    int k = snprintf(out, n, "%s/%s", real, base);
    return k < 0 || (size_t)k >= n ? -1 : 0; /* too long to compare: not resolved */
}

/* --record and --checkpoint-at must not replace the run's inputs (the scenario, the replayed
 * log, the checkpoint resumed) or its other outputs (report.json, trajectory.csv, summary.png,
 * the video, each other): compared as files (device and inode) where they exist, and as
 * canonical paths. Returns 0 or a usage error (2). */
int ns_run_check_out_path(const NsRunOpts *o, const char *out, const char *flag)
{
    if (!out)
        return 0;
    char msg[200];
    if (out == o->checkpoint) { /* said now, not at T: a folder, a device, a missing folder */
        char why[200];
        const char *slash = strrchr(out, '/');
        char dir[PATH_MAX];
        snprintf(dir, sizeof dir, "%.*s", slash ? (int)(slash - out == 0 ? 1 : slash - out) : 1,
                 slash ? out : ".");
        struct stat ds;
        if (ns_out_replaceable(out, "--checkpoint-at", why, (int)sizeof why) != 0)
            return usage_error("%s", why);
        if (stat(dir, &ds) != 0 || !S_ISDIR(ds.st_mode))
            return usage_error("--checkpoint-at '%s': its folder does not exist", out);
    }
    struct stat rs, st;
    bool exists = stat(out, &rs) == 0;
    const char *inputs[3] = {o->scenario, o->replay, o->resume};
    for (int k = 0; k < 3; k++)
        if (inputs[k] && exists && stat(inputs[k], &st) == 0 && st.st_dev == rs.st_dev &&
            st.st_ino == rs.st_ino) {
            snprintf(msg, sizeof msg, "%s '%%s': that is the run's own input", flag);
            return usage_error(msg, out);
        }
    char rec[PATH_MAX + 256], other[PATH_MAX + 256], path[PATH_MAX + 64];
    if (canonical(out, rec, sizeof rec) != 0)
        return 0; /* its folder does not exist: the file cannot be written, said later */
    static const char *const outs[4] = {"report.json", "trajectory.csv", "summary.png", "frames"};
    const char *files[2] = {o->video, out == o->record ? o->checkpoint : o->record};
    for (int k = 0; k < 6; k++) {
        if (k < 4)
            snprintf(path, sizeof path, "%s/%s", o->out_dir, outs[k]);
        else if (files[k - 4])
            snprintf(path, sizeof path, "%s", files[k - 4]);
        else
            continue;
        if (canonical(path, other, sizeof other) == 0 && strcmp(rec, other) == 0) {
            snprintf(msg, sizeof msg, "%s '%%s': that is another output of the run", flag);
            return usage_error(msg, out);
        }
    }
    return 0;
}

int ns_run_check_record_path(const NsRunOpts *o)
{
    return ns_run_check_out_path(o, o->record, "--record");
}

int ns_cmd_run(int argc, char **argv)
{
    NsRun r;
    memset(&r, 0, sizeof r);
    r.sim_ref = r.act_ref = r.co_ref = LUA_NOREF;
    int pa = parse_args(argc, argv, &r.opt);
    if (pa)
        return pa == 1 ? 0 : pa;
    char err[1024] = "";
    if (ns_run_prior_plan_read(&r, err, sizeof err)) { /* before -o's folder is made */
        ns_one_line(err);
        fprintf(stderr, "needlesim: %s\n", err);
        ns_run_free(&r);
        return 1;
    }
    ns_cleanup_install();
    int rc = ns_run_outputs_prepare(&r, err, sizeof err) ? -2 : -1;
    /* --record and the checkpoint checked once -o's folder exists (they may be inside it). */
    if (rc == -1 && (ns_run_check_out_path(&r.opt, r.opt.record, "--record") ||
                     ns_run_check_out_path(&r.opt, r.opt.checkpoint, "--checkpoint-at"))) {
        ns_run_outputs_remove(&r);
        ns_run_free(&r);
        return 2;
    }
    /* --resume: the checkpoint's settings are the run's (before the scenario is loaded). */
    if (rc == -1 && r.opt.resume && ns_run_checkpoint_open(&r, err, sizeof err))
        rc = -2;
    r.keep_views = r.opt.checkpoint && !r.opt.replay;
    if (rc == -1 && ns_run_load(&r, err, sizeof err) == 0)
        rc = ns_run_checkpoint_hash_inputs(&r, err, sizeof err);
    rc = rc ? rc : ns_run_open_logs(&r, err, sizeof err);
    if (rc == 0)
        ns_run_traj_header(&r);
    rc = rc ? rc : ns_run_build(&r, err, sizeof err);
    if (rc == 0 && !r.opt.no_render)
        rc = ns_run_render_setup(&r, err, sizeof err);
    rc = rc ? rc : ns_run_loop(&r, err, sizeof err);
    NsRunResults res;
    memset(&res, 0, sizeof res);
    uint64_t hash = 0;
    rc = rc ? rc : ns_run_end(&r, &res, &hash, err, sizeof err);
    rc = rc ? rc : ns_run_write_report(&r, &res, hash, err, sizeof err);
    rc = rc ? rc : ns_run_outputs_commit(&r, err, sizeof err);
    if (rc) {
        ns_run_outputs_remove(&r);
        /* Messages that name their scenario file and line (or say needlesim) print as they
         * are, as in `needlesim check`; the others get the program's name. */
        if (r.progress_shown)
            fputs("\r\033[K", stderr); /* the progress line goes before the message */
        size_t n = strlen(r.opt.scenario);
        bool located = strncmp(err, "needlesim", 9) == 0 || strncmp(err, r.opt.scenario, n) == 0;
        ns_one_line(err);
        fprintf(stderr, "%s%s\n", located ? "" : "needlesim: ", err);
    } else {
        if (r.note[0]) /* a warning about the replayed log: said once the run has succeeded */
            fprintf(stderr, "%s\n", r.note);
        if (!r.opt.quiet)
            print_summary(&r, &res, hash);
    }
    ns_run_results_free(&res);
    ns_run_free(&r);
    return rc ? 1 : 0;
}
