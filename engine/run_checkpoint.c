/* Checkpoints of a run (docs/checkpoints.md): `--checkpoint-at T FILE` writes, after the first
 * step that reaches simulated time T, everything the rest of the run depends on; `--resume
 * FILE` continues from it to the same end, bit for bit.
 *
 * The file: a header (the build's layout fingerprint, the scenario file's hash, the settings),
 * the run's own state (counters, statistics, seeds, events, obstacles, hints), the views the
 * script saw at every tick, the trajectory so far, the world (sim/snapshot.h: tissue, needle,
 * coupling, solver caches) and a checksum of it all.
 *
 * The script's Lua state is not written: a resumed run starts the script afresh and runs it
 * tick by tick against the views it saw then (the `sim` table rebuilt from them, no physics
 * stepped), checking that it sets the same controls each tick; a script is a function of what
 * `sim` shows it, so it arrives where it was. */
#include <elf.h>
#include <link.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "control_log.h"
#include "err.h"
#include "file_in.h"
#include "ns_config.h"
#include "ns_limits.h"
#include "out_files.h"
#include "run.h"
#include "snapshot.h"

#define CHECKPOINT_MAGIC "NSCKPT01"

/* The header: settings a resumed run must share with the run that wrote it. */
typedef struct NsCheckpointHeader {
    char magic[8];
    uint64_t fingerprint;       /* ns_pack_fingerprint of the writer */
    char version[64];           /* NS_VERSION */
    unsigned char build_id[32]; /* the writer's ELF build ID (its first 32 bytes; 0s if none) */
    uint64_t scenario_hash;     /* FNV-1a of the scenario file's bytes (control_log.h) */
    uint64_t replay_hash;       /* of the --replay log, 0 without one */
    int nsets;
    char sets[32][256];
    long steps_opt; /* --steps (0: none) */
    int threads, solver;
    long steps; /* steps taken at the checkpoint */
    double dt, t;
} NsCheckpointHeader;

/* The program's ELF build ID (the linker's hash of the binary): a checkpoint is read only by the
 * binary that wrote it, whose structures' layouts are the file's. */
static int note_of(struct dl_phdr_info *info, size_t size, void *data)
{
    (void)size;
    unsigned char *id = data;
    for (int i = 0; i < info->dlpi_phnum; i++) {
        const ElfW(Phdr) *ph = &info->dlpi_phdr[i];
        if (ph->p_type != PT_NOTE)
            continue;
        const unsigned char *n = (const unsigned char *)(info->dlpi_addr + ph->p_vaddr);
        size_t off = 0;
        while (off + sizeof(ElfW(Nhdr)) <= ph->p_memsz) {
            const ElfW(Nhdr) *nh = (const ElfW(Nhdr) *)(n + off);
            size_t name = (nh->n_namesz + 3) & ~(size_t)3, desc = (nh->n_descsz + 3) & ~(size_t)3;
            const unsigned char *d = n + off + sizeof *nh + name;
            if (nh->n_type == NT_GNU_BUILD_ID && nh->n_namesz == 4 &&
                memcmp(n + off + sizeof *nh, "GNU", 4) == 0) {
                memcpy(id, d, nh->n_descsz < 32 ? nh->n_descsz : 32);
                return 1;
            }
            off += sizeof *nh + name + desc;
        }
    }
    return 1; /* the first object is the program itself */
}

static void build_id(unsigned char id[32])
{
    memset(id, 0, 32);
    dl_iterate_phdr(note_of, id);
}

int ns_run_views_push(NsRun *r, const NsTickView *v, const double *tx)
{
    size_t nt = 3 * (size_t)r->spec.target_count;
    if (r->view_n == r->view_cap) {
        long cap = r->view_cap ? 2 * r->view_cap : 1024;
        NsTickView *nv = realloc(r->views, (size_t)cap * sizeof *nv);
        if (!nv)
            return -1;
        r->views = nv;
        double *nx = realloc(r->view_tx, (size_t)cap * nt * sizeof *nx + sizeof *nx);
        if (!nx)
            return -1;
        r->view_tx = nx;
        r->view_cap = cap;
    }
    r->views[r->view_n] = *v;
    memcpy(r->view_tx + (size_t)r->view_n * nt, tx, nt * sizeof *tx);
    r->view_n++;
    return 0;
}

/* An array of the run that exists when reading: freed and read again. */
static void repack(NsPack *p, void **ptr, size_t elem, size_t count, size_t cap)
{
    if (!p->writing) {
        free(*ptr);
        *ptr = NULL;
    }
    ns_pack_array(p, ptr, elem, count, cap);
}
#define REPACK(p, ptr, count, cap)                                                                 \
    repack((p), (void **)&(ptr), sizeof *(ptr), (size_t)(count), (size_t)(cap))

static void series_pack(NsPack *p, NsSeries *s)
{
    NS_PACK(p, s->n);
    NS_PACK(p, s->cap);
    REPACK(p, s->v, s->n, s->cap);
    if (!p->writing && (s->n < 0 || s->n > s->cap || (s->cap && !s->v)))
        ns_pack_fail(p, "bad statistics series");
}

/* The run's own state between ticks (not the world, not the script). */
static int run_state_pack(NsPack *p, NsRun *r)
{
    const NsRunSpec *sp = &r->spec;
    ns_pack_tag(p, "RUN ");
    NS_PACK(p, r->steps);
    NS_PACK(p, r->factorizations);
    NS_PACK(p, r->consistent);
    NS_PACK(p, r->warn);
    NS_PACK(p, r->debrief.twists);
    NS_PACK(p, r->debrief.twisting);
    NS_PACK(p, r->repaired);
    /* The minima so far; the watch's copy is the mesh as built, which the next look compares
     * with the resumed mesh (every tet changed since counted again: the same minimum). */
    NS_PACK(p, r->dw.min_rest_deg);
    NS_PACK(p, r->dw.min_world_deg);
    NS_PACK(p, r->max_axial);
    NS_PACK(p, r->last_axial);
    NS_PACK(p, r->path_cut);
    NS_PACK(p, r->last_tip);
    NS_PACK(p, r->exited);
    NS_PACK(p, r->needles);
    NS_PACK(p, r->last_fr);
    NS_PACK(p, r->last_cutting);
    NS_PACK(p, r->tip_hint);
    NS_PACK(p, r->insertions);
    NS_PACK(p, r->prev_v);
    NS_PACK(p, r->more);
    NS_PACK(p, r->entered);
    NS_PACK(p, r->peak_axial);
    NS_PACK(p, r->punctures);
    /* the current needle's entry (act.next_needle replaces the scenario's) */
    NS_PACK(p, r->spec.entry_point);
    NS_PACK(p, r->spec.entry_dir);
    NS_PACK(p, r->spec.has_bevel_toward);
    NS_PACK(p, r->spec.bevel_toward);
    NsSeries *s[8] = {&r->step_ms,   &r->total_ms,  &r->lcp_ms, &r->tissue_ms,
                      &r->needle_ms, &r->remesh_ms, &r->trials, &r->iterations};
    for (int k = 0; k < 8; k++)
        series_pack(p, s[k]);
    REPACK(p, r->target_hint, sp->target_count, sp->target_count + 1);
    REPACK(p, r->marker_hint, sp->marker_count, sp->marker_count + 1);
    REPACK(p, r->obst, sp->obstacle_count, sp->obstacle_count + 1);
    NS_PACK(p, r->seed_n);
    NS_PACK(p, r->seed_cap);
    REPACK(p, r->seeds, r->seed_n, r->seed_cap);
    NS_PACK(p, r->event_n);
    NS_PACK(p, r->event_cap);
    REPACK(p, r->events, r->event_n, r->event_cap);
    if (!p->writing &&
        (r->seed_n < 0 || r->seed_n > r->seed_cap || r->event_n < 0 || r->event_n > r->event_cap ||
         !r->target_hint || !r->marker_hint || !r->obst))
        ns_pack_fail(p, "bad run state");
    /* The tip-reached moments taken (pictures): a run that renders keeps them. */
    bool *reached = calloc((size_t)sp->target_count + 1, sizeof *reached);
    if (!reached)
        return ns_pack_fail(p, "out of memory");
    if (p->writing && r->reached)
        memcpy(reached, r->reached, (size_t)sp->target_count * sizeof *reached);
    ns_pack_bytes(p, reached, (size_t)sp->target_count * sizeof *reached);
    if (!p->writing && r->reached)
        memcpy(r->reached, reached, (size_t)sp->target_count * sizeof *reached);
    free(reached);
    return p->failed ? -1 : 0;
}

/* The views of the script's ticks so far. */
static int views_pack(NsPack *p, NsRun *r)
{
    size_t nt = 3 * (size_t)r->spec.target_count;
    ns_pack_tag(p, "VIEW");
    NS_PACK(p, r->view_n);
    if (!p->writing && (r->view_n < 0 || r->view_n > NS_LIMIT_STEPS))
        return ns_pack_fail(p, "bad view count");
    if (!p->writing)
        r->view_cap = r->view_n;
    REPACK(p, r->views, r->view_n, r->view_n);
    REPACK(p, r->view_tx, (size_t)r->view_n * nt, (size_t)r->view_n * nt + 1);
    return p->failed ? -1 : 0;
}

/* The trajectory's rows so far (after its header): written from the file, read into it. */
static int traj_pack(NsPack *p, NsRun *r)
{
    ns_pack_tag(p, "TRAJ");
    char *bytes = NULL;
    long n = 0;
    if (p->writing && r->traj) {
        fflush(r->traj);
        long end = ftell(r->traj);
        n = end > r->traj_start ? end - r->traj_start : 0;
        FILE *f = fopen(r->traj_tmp, "rb");
        bytes = n ? malloc((size_t)n) : NULL;
        if (n && (!f || !bytes || fseek(f, r->traj_start, SEEK_SET) != 0 ||
                  fread(bytes, 1, (size_t)n, f) != (size_t)n))
            ns_pack_fail(p, "could not read the trajectory back (%s)", r->traj_tmp);
        if (f)
            fclose(f);
    }
    NS_PACK(p, n);
    ns_pack_array(p, (void **)&bytes, 1, (size_t)(n > 0 ? n : 0), (size_t)(n > 0 ? n : 0));
    if (!p->writing && !p->failed && r->traj && n > 0 &&
        fwrite(bytes, 1, (size_t)n, r->traj) != (size_t)n)
        ns_pack_fail(p, "could not write the trajectory");
    free(bytes);
    return p->failed ? -1 : 0;
}

/* The header of this run (writing). */
static int header_fill(NsRun *r, NsCheckpointHeader *h, char *err, int err_sz)
{
    memset(h, 0, sizeof *h);
    memcpy(h->magic, CHECKPOINT_MAGIC, 8);
    h->fingerprint = ns_pack_fingerprint();
    snprintf(h->version, sizeof h->version, "%s", NS_VERSION);
    build_id(h->build_id);
    (void)err, (void)err_sz;
    h->scenario_hash = r->ck_scenario_hash;
    h->replay_hash = r->ck_replay_hash;
    h->nsets = r->opt.nsets;
    for (int k = 0; k < r->opt.nsets; k++)
        snprintf(h->sets[k], sizeof h->sets[k], "%s", r->opt.sets[k]);
    h->steps_opt = r->opt.steps;
    h->threads = r->opt.threads;
    h->solver = r->opt.solver;
    h->steps = r->steps;
    h->dt = r->spec.dt;
    h->t = (double)r->steps * r->spec.dt;
    return 0;
}

int ns_run_checkpoint_hash_inputs(NsRun *r, char *err, int err_sz)
{
    if (!r->opt.checkpoint || r->opt.resume) /* a resumed run has the checkpoint's */
        return 0;
    return ns_file_hash(r->opt.scenario, NS_LIMIT_SCRIPT_FILE_BYTES, "scenario file",
                        &r->ck_scenario_hash, err, err_sz) ||
                   (r->opt.replay && ns_file_hash(r->opt.replay, NS_LIMIT_LOG_FILE_BYTES,
                                                  "control log", &r->ck_replay_hash, err, err_sz))
               ? -1
               : 0;
}

int ns_run_checkpoint_maybe(NsRun *r, char *err, int err_sz)
{
    if (!r->opt.checkpoint || r->checkpointed ||
        (double)r->steps * r->spec.dt < r->opt.checkpoint_at - 1e-9 * r->spec.dt)
        return 0;
    NsCheckpointHeader h;
    if (header_fill(r, &h, err, err_sz))
        return -1;
    size_t n = strlen(r->opt.checkpoint) + 6;
    char *part = malloc(n);
    if (!part) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    snprintf(part, n, "%s.part", r->opt.checkpoint);
    FILE *f = ns_out_create_part(part, "the checkpoint", err, err_sz);
    if (!f) {
        free(part);
        return -1;
    }
    NsPack p;
    ns_pack_writer(&p, f);
    ns_pack_bytes(&p, &h, sizeof h);
    ns_pack_checksum(&p); /* the header's own, checked before anything in it is used */
    run_state_pack(&p, r);
    views_pack(&p, r);
    traj_pack(&p, r);
    ns_world_pack(&p, &r->tissue, &r->rod, &r->c);
    ns_pack_checksum(&p);
    int rc = p.failed ? -1 : 0;
    if (fclose(f) != 0 && rc == 0)
        ns_pack_fail(&p, "write failed"), rc = -1;
    if (rc == 0 && ns_out_commit(part, r->opt.checkpoint) != 0)
        ns_pack_fail(&p, "could not rename it into place"), rc = -1;
    if (rc) {
        ns_out_remove_part(part);
        ns_set_err(err, err_sz, "%s: checkpoint: %s", r->opt.checkpoint, p.err);
    } else {
        r->checkpointed = true;
        r->keep_views = false; /* one checkpoint a run: the views are not needed again */
        free(r->views);
        free(r->view_tx);
        r->views = NULL;
        r->view_tx = NULL;
        r->view_n = r->view_cap = 0;
        if (!r->opt.quiet)
            fprintf(stderr, "%s%s: checkpoint at step %ld (t = %.6g s), %ld bytes\n",
                    r->progress_shown ? "\r\033[K" : "", r->opt.checkpoint, r->steps,
                    (double)r->steps * r->spec.dt, (long)p.pos);
    }
    ns_pack_free(&p);
    free(part);
    return rc;
}

/* A setting given on the command line that the checkpoint's run did not have. */
static int mismatch(const NsRun *r, const char *what, char *err, int err_sz)
{
    ns_set_err(err, err_sz, "%s: the checkpoint was written with another %s than this run's",
               r->opt.resume, what);
    return -1;
}

int ns_run_checkpoint_open(NsRun *r, char *err, int err_sz)
{
    long long size = 0;
    int fd = ns_file_open_regular(r->opt.resume, (long long)NS_PACK_MAX_BYTES, "checkpoint", &size,
                                  err, err_sz);
    if (fd < 0)
        return -1;
    r->resume_f = fdopen(fd, "rb");
    NsCheckpointHeader *h = calloc(1, sizeof *h);
    r->resume_pack = calloc(1, sizeof *r->resume_pack);
    if (!r->resume_f || !h || !r->resume_pack) {
        if (!r->resume_f)
            close(fd);
        free(h);
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    r->resume_hdr = h;
    NsPack *p = r->resume_pack;
    ns_pack_reader(p, r->resume_f, NULL, (size_t)size);
    if (ns_pack_bytes(p, h, sizeof *h) != 0 || memcmp(h->magic, CHECKPOINT_MAGIC, 8) != 0) {
        ns_set_err(err, err_sz, "%s: not a needlesim checkpoint", r->opt.resume);
        return -1;
    }
    if (ns_pack_checksum(p) != 0) {
        ns_set_err(err, err_sz, "%s: damaged checkpoint header (%s)", r->opt.resume, p->err);
        return -1;
    }
    h->version[sizeof h->version - 1] = '\0';
    unsigned char id[32];
    build_id(id);
    if (h->fingerprint != ns_pack_fingerprint() || strcmp(h->version, NS_VERSION) != 0 ||
        memcmp(h->build_id, id, sizeof id) != 0) {
        ns_set_err(err, err_sz,
                   "%s: written by another build of needlesim (%s); a checkpoint is read only by "
                   "the build that wrote it",
                   r->opt.resume, h->version);
        return -1;
    }
    if (h->nsets < 0 || h->nsets > 32 || h->steps < 0 || h->steps > NS_LIMIT_STEPS ||
        h->threads < 1 || h->threads > 64 || h->steps_opt < 0 || h->steps_opt > NS_LIMIT_STEPS ||
        (h->solver != NS_COUPLED_PAPER && h->solver != NS_COUPLED_SCHUR)) {
        ns_set_err(err, err_sz, "%s: damaged checkpoint header", r->opt.resume);
        return -1;
    }
    uint64_t sc_hash = 0;
    if (ns_file_hash(r->opt.scenario, NS_LIMIT_SCRIPT_FILE_BYTES, "scenario file", &sc_hash, err,
                     err_sz))
        return -1;
    if (sc_hash != h->scenario_hash) {
        ns_set_err(err, err_sz, "%s: the checkpoint is of another scenario file than %s",
                   r->opt.resume, r->opt.scenario);
        return -1;
    }
    /* The settings: the checkpoint's, and any given here must be the same. */
    bool sets_same = r->opt.nsets == 0 || r->opt.nsets == h->nsets;
    for (int i = 0; sets_same && i < r->opt.nsets; i++) {
        bool found = false;
        for (int k = 0; k < h->nsets && !found; k++)
            found = strncmp(r->opt.sets[i], h->sets[k], sizeof h->sets[k]) == 0;
        sets_same = found;
    }
    if (!sets_same)
        return mismatch(r, "--set values", err, err_sz);
    if (r->opt.steps && r->opt.steps != h->steps_opt)
        return mismatch(r, "--steps", err, err_sz);
    if (r->opt.threads_given && r->opt.threads != h->threads)
        return mismatch(r, "--threads", err, err_sz);
    if (r->opt.solver_given && r->opt.solver != h->solver)
        return mismatch(r, "--solver", err, err_sz);
    if ((h->replay_hash != 0) != (r->opt.replay != NULL))
        return mismatch(r, "--replay", err, err_sz);
    if (r->opt.replay) {
        uint64_t lh = 0;
        if (ns_file_hash(r->opt.replay, NS_LIMIT_LOG_FILE_BYTES, "control log", &lh, err, err_sz))
            return -1;
        if (lh != h->replay_hash)
            return mismatch(r, "--replay log", err, err_sz);
    }
    r->opt.nsets = 0; /* the header's, by the command line's rules (the header outlives the run) */
    for (int k = 0; k < h->nsets; k++) {
        h->sets[k][sizeof h->sets[k] - 1] = '\0';
        if (ns_run_opt_set(&r->opt, h->sets[k]) != NULL) {
            ns_set_err(err, err_sz, "%s: damaged checkpoint header (--set %d)", r->opt.resume, k);
            return -1;
        }
    }
    r->ck_scenario_hash = h->scenario_hash;
    r->ck_replay_hash = h->replay_hash;
    r->opt.steps = h->steps_opt;
    r->opt.threads = h->threads;
    r->opt.solver = h->solver;
    return 0;
}

/* The resumed run's control log, when it records one: the rows before the checkpoint. */
static void record_rows(NsRun *r)
{
    for (long k = 0; r->rec && k < r->steps; k++) {
        const NsControl *c = r->opt.replay ? &r->replay.rows[k] : &r->views[k].ctl;
        ns_control_log_write_row(r->rec, (double)k * r->spec.dt, c);
    }
}

int ns_run_checkpoint_resume(NsRun *r, char *err, int err_sz)
{
    NsPack *p = r->resume_pack;
    const NsCheckpointHeader *h = r->resume_hdr;
    if (h->dt != r->spec.dt) {
        ns_set_err(err, err_sz, "%s: the checkpoint's dt %.17g s is not the scenario's %.17g s",
                   r->opt.resume, h->dt, r->spec.dt);
        return -1;
    }
    run_state_pack(p, r);
    views_pack(p, r);
    traj_pack(p, r);
    /* The world as it was: the one built from the scenario is dropped. */
    ns_coupled_free(&r->c);
    ns_rod_free(&r->rod);
    ns_tissue_free(&r->tissue);
    ns_world_pack(p, &r->tissue, &r->rod, &r->c);
    ns_pack_checksum(p);
    if (!p->failed && r->steps != h->steps)
        ns_pack_fail(p, "the run's state is not at the header's step");
    bool scripted = !r->opt.replay; /* every tick ran the script side (run_script.c) */
    if (!p->failed && scripted && r->view_n != r->steps)
        ns_pack_fail(p, "%ld script views for %ld steps", r->view_n, r->steps);
    if (!p->failed && r->opt.replay && r->replay.n < r->steps)
        ns_pack_fail(p, "the log is shorter than the checkpoint's %ld steps", r->steps);
    if (p->failed) {
        ns_set_err(err, err_sz, "%s: %s", r->opt.resume, p->err);
        return -1;
    }
    /* The script brought to the checkpoint's tick. */
    for (long k = 0; scripted && k < r->view_n; k++)
        if (ns_run_script_replay_tick(r, k, err, err_sz))
            return -1;
    record_rows(r);
    r->keep_views = scripted && r->opt.checkpoint != NULL;
    if (r->opt.checkpoint && r->opt.checkpoint_at <= h->t) {
        ns_set_err(err, err_sz, "--checkpoint-at %g s: not after the resumed checkpoint's %g s",
                   r->opt.checkpoint_at, h->t);
        return -1;
    }
    fclose(r->resume_f); /* the header stays: the run's --set values point into it */
    r->resume_f = NULL;
    free(r->resume_pack);
    r->resume_pack = NULL;
    memcpy(r->last_tip, ns_run_tip(r), sizeof r->last_tip);
    if (r->rendering && (r->opt.frames || r->opt.video))
        return ns_run_render_now(r, NULL, false, NULL, err, err_sz);
    return 0;
}

void ns_run_checkpoint_free(NsRun *r)
{
    if (r->resume_f)
        fclose(r->resume_f);
    r->resume_f = NULL;
    free(r->resume_pack);
    r->resume_pack = NULL;
    free(r->resume_hdr);
    r->resume_hdr = NULL;
}
