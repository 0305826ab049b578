/* A run's output folder (run.h): created, checked, its temporary files, the trajectory. */
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

/* ---- outputs ---- */

char *ns_run_path_join(const char *dir, const char *name)
{
    size_t n = strlen(dir) + strlen(name) + 2;
    char *p = malloc(n);
    if (p)
        snprintf(p, n, "%s/%s", dir, name);
    return p;
}

/* Creates DIR (and its parents) when missing, removes the report and trajectory of an earlier
 * run there (this run replaces them; a failed one leaves neither), and opens the trajectory's
 * temporary file, which also proves DIR writable before anything runs. */
/* Removes the folders this run made for -o, deepest first, each only if empty. */
static void remove_made(NsRun *r)
{
    if (!r->made_dir)
        return;
    size_t n = strlen(r->opt.out_dir);
    char *path = malloc(n + 1);
    if (path) {
        memcpy(path, r->opt.out_dir, n + 1);
        for (size_t i = n; i >= r->made_from && i > 0; i--) {
            if (path[i] != '/' && path[i] != '\0')
                continue;
            path[i] = '\0';
            ns_cleanup_forget(path);
            if (rmdir(path) != 0)
                break;
        }
        free(path);
    }
    r->made_dir = false;
}

int ns_run_outputs_prepare(NsRun *r, char *err, int err_sz)
{
    size_t n = strlen(r->opt.out_dir);
    if (n == 0) {
        ns_set_err(err, err_sz, "-o: the output folder must be named (got an empty path)");
        return -2;
    }
    char *path = malloc(n + 1);
    if (!path) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    memcpy(path, r->opt.out_dir, n + 1);
    for (size_t i = 1; i <= n; i++) { /* mkdir -p */
        if (path[i] != '/' && path[i] != '\0')
            continue;
        char c = path[i];
        path[i] = '\0';
        struct stat sb;
        if (stat(path, &sb) != 0) {
            if (mkdir(path, 0777) != 0) {
                ns_set_err(err, err_sz, "cannot create output folder '%s': %s", path,
                           strerror(errno));
                free(path);
                return -1;
            }
            if (!r->made_dir)
                r->made_from = i; /* the first folder this run made: path[0 .. i) */
            r->made_dir = true;
            ns_cleanup_add(path); /* a second stop signal removes it too (if empty) */
        } else if (!S_ISDIR(sb.st_mode)) {
            ns_set_err(err, err_sz, "cannot create output folder '%s': '%s' is not a folder",
                       r->opt.out_dir, path);
            free(path);
            return -1;
        }
        path[i] = c;
    }
    free(path);
    r->traj_tmp = ns_run_path_join(r->opt.out_dir, ".trajectory.csv.part");
    r->report_tmp = ns_run_path_join(r->opt.out_dir, ".report.json.part");
    char *old_t = ns_run_path_join(r->opt.out_dir, "trajectory.csv");
    char *old_r = ns_run_path_join(r->opt.out_dir, "report.json");
    int rc = 0;
    if (!r->traj_tmp || !r->report_tmp || !old_t || !old_r) {
        ns_set_err(err, err_sz, "out of memory");
        rc = -1;
    }
    /* Every final name this run will replace must be a regular file (or absent), checked
     * before anything is removed: the run fails whole or not at all. */
    if (rc == 0 &&
        (ns_out_replaceable(old_t, "the trajectory", err, err_sz) ||
         ns_out_replaceable(old_r, "the report", err, err_sz) ||
         (r->opt.record && ns_out_replaceable(r->opt.record, "the control log", err, err_sz)) ||
         (r->opt.video && ns_out_replaceable(r->opt.video, "the video", err, err_sz))))
        rc = -1;
    /* An earlier run's outputs stay until this run succeeds: the renames at the end replace
     * them, and a failed run leaves them as they were. */
    free(old_t);
    free(old_r);
    if (rc == 0 && ns_run_render_check_old(r->opt.out_dir, r->opt.frames, err, err_sz))
        rc = -1;
    if (rc == 0) {
        r->traj = ns_out_create_part(r->traj_tmp, "the trajectory", err, err_sz);
        if (!r->traj)
            rc = -1;
    }
    if (rc != 0)
        remove_made(r);
    return rc;
}

void ns_run_traj_header(NsRun *r)
{
    fprintf(r->traj, "t_s,tip_x_m,tip_y_m,tip_z_m,depth_m,axial_force_n,v_insert_m_s,"
                     "twist_rate_rad_s,n_static,n_dyn_pos,n_dyn_neg,cutting");
    for (int i = 0; i < r->spec.marker_count; i++) {
        const char *n = r->spec.markers[i].name;
        fprintf(r->traj, ",%s_x_m,%s_y_m,%s_z_m", n, n, n);
    }
    fputc('\n', r->traj);
    r->traj_start = ftell(r->traj);
}

void ns_run_outputs_remove(NsRun *r)
{
    if (r->rec)
        fclose(r->rec);
    r->rec = NULL;
    if (r->rec_tmp)
        ns_out_remove_part(r->rec_tmp);
    if (r->traj)
        fclose(r->traj);
    r->traj = NULL;
    if (r->traj_tmp)
        ns_out_remove_part(r->traj_tmp);
    if (r->report_tmp)
        ns_out_remove_part(r->report_tmp);
    if (r->row_tmp)
        ns_out_remove_part(r->row_tmp);
    if (r->rendering) { /* also closes ffmpeg */
        ns_run_render_abort(&r->rr);
        r->rendering = false;
    }
    remove_made(r);
}

int ns_run_outputs_commit(NsRun *r, char *err, int err_sz)
{
    int rc = 0;
    if (rc == 0) {
        int bad = ferror(r->traj) != 0;
        if ((fclose(r->traj) != 0) | bad) {
            r->traj = NULL;
            ns_set_err(err, err_sz, "cannot write the trajectory: %s", strerror(errno));
            rc = -1;
        }
        r->traj = NULL;
    }
    if (rc == 0) {
        char *traj = ns_run_path_join(r->opt.out_dir, "trajectory.csv");
        char *rep = ns_run_path_join(r->opt.out_dir, "report.json");
        if (!traj || !rep || ns_out_commit(r->traj_tmp, traj) ||
            ns_out_commit(r->report_tmp, rep)) {
            ns_set_err(err, err_sz, "cannot write to output folder '%s': %s", r->opt.out_dir,
                       strerror(errno));
            if (traj)
                remove(traj);
            rc = -1;
        }
        /* --score-row: after the report, which it summarizes */
        char *row = r->row_tmp ? ns_run_path_join(r->opt.out_dir, "score_row.csv") : NULL;
        if (rc == 0 && r->row_tmp && (!row || ns_out_commit(r->row_tmp, row))) {
            ns_set_err(err, err_sz, "cannot write to output folder '%s': %s", r->opt.out_dir,
                       strerror(errno));
            remove(traj);
            remove(rep);
            rc = -1;
        }
        free(row);
        /* The pictures before the log: they are part of the run's outputs. */
        if (rc == 0 && r->rendering && ns_run_render_commit(&r->rr, err, err_sz)) {
            remove(traj);
            remove(rep);
            rc = -1;
        }
        if (rc == 0 && ns_run_dosimetry_commit(r)) {
            ns_set_err(err, err_sz, "cannot write to output folder '%s': %s", r->opt.out_dir,
                       strerror(errno));
            remove(traj);
            remove(rep);
            rc = -1;
        }
        /* The control log last: a log on disk means the run and its report are there. */
        if (rc == 0 && r->rec) {
            int bad = ferror(r->rec) != 0;
            bad |= fclose(r->rec) != 0;
            r->rec = NULL;
            if (bad || ns_out_commit(r->rec_tmp, r->opt.record) != 0) {
                ns_set_err(err, err_sz, "cannot write the control log '%s': %s", r->opt.record,
                           strerror(errno));
                remove(traj);
                remove(rep);
                ns_run_dosimetry_uncommit(r);
                rc = -1;
            }
        }
        free(traj);
        free(rep);
    }
    return rc;
}
