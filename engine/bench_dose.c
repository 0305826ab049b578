/* needlesim bench --dose [--repeat N] [--threads N] [--json]
 *
 * Issue 38's bar "dose computation for the full implant <= 1 s (benchmark, median)": the TG-43U1
 * dose grid (sim/dose.h) of a synthetic full implant, timed over repetitions. The implant: 20
 * needles on a 5 mm template grid (x in -10..10 mm, y in -7.5..7.5 mm), 4 seeds each 10 mm apart
 * along the needle (z = -15, -5, 5, 15 mm), 80 I-125 model 6711 seeds of 0.5 U pointing along
 * z; the grid: a 40 x 40 x 40 mm prostate-sized box centred on the implant at 1 mm (64,000
 * voxels). Only the grid is timed (the table is read once, before). The figure is wall-clock
 * time (median and p95 of the repeats); the process's CPU time is printed beside it, since on a
 * shared machine the wall clock also counts the time other programs held the cores. */
#include "commands.h"

#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "dose.h"
#include "dose_table.h"
#include "json.h"

static const char usage[] = "usage: needlesim bench --dose [--repeat N] [--threads N] [--json]\n";

#define DOSE_REPEAT_MAX 1000
#define IMPLANT_SEEDS   80
#define SEED_SK_U       0.5

static double now_ms(clockid_t clock)
{
    struct timespec ts;
    clock_gettime(clock, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The synthetic implant above; returns the seed count. */
static int implant(NsDoseSeed *seeds)
{
    int n = 0;
    for (int ix = 0; ix < 5; ix++)
        for (int iy = 0; iy < 4; iy++)
            for (int iz = 0; iz < 4; iz++) {
                NsDoseSeed *s = &seeds[n++];
                s->pos[0] = (-10.0 + 5.0 * ix) * 1e-3;
                s->pos[1] = (-7.5 + 5.0 * iy) * 1e-3;
                s->pos[2] = (-15.0 + 10.0 * iz) * 1e-3;
                s->axis[0] = s->axis[1] = 0.0;
                s->axis[2] = 1.0;
                s->sk = SEED_SK_U * NS_TG43_UNIT_U;
            }
    return n;
}

static int parse_int(const char *opt, const char *v, int lo, int hi, int *out)
{
    char *end;
    long x = v ? strtol(v, &end, 10) : 0;
    if (!v || *end || end == v || x < lo || x > hi) {
        fprintf(stderr, "needlesim: bench --dose: %s needs an integer in %d..%d\n%s", opt, lo, hi,
                usage);
        return -1;
    }
    *out = (int)x;
    return 0;
}

static double median(const double *v, int n)
{
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/* ms: wall-clock times, cpu: the process's CPU times, both sorted. */
static void print_result(bool json, const double *ms, const double *cpu, int repeat, int threads,
                         const NsDoseGrid *g, int seeds)
{
    double med = median(ms, repeat), cpu_med = median(cpu, repeat);
    int k95 = (int)ceil(0.95 * repeat) - 1;
    double p95 = ms[k95 < 0 ? 0 : k95];
    long voxels = (long)g->n[0] * g->n[1] * g->n[2];
    double dmax = 0.0, center;
    for (long v = 0; v < voxels; v++)
        dmax = fmax(dmax, g->dose[v]);
    center = g->dose[((long)g->n[2] / 2 * g->n[1] + g->n[1] / 2) * g->n[0] + g->n[0] / 2];
    if (!json) {
        printf("dose grid: %d seeds (I-125 6711, %.1f U), %d x %d x %d voxels at %.1f mm, "
               "%d thread%s\n",
               seeds, SEED_SK_U, g->n[0], g->n[1], g->n[2], g->spacing * 1e3, threads,
               threads == 1 ? "" : "s");
        printf("dose_ms: median %.2f, p95 %.2f, min %.2f, max %.2f (%d repeats); CPU time "
               "median %.2f ms\n",
               med, p95, ms[0], ms[repeat - 1], repeat, cpu_med);
        printf("total dose to full decay: %.1f Gy near the centre (voxel (%d,%d,%d)), largest "
               "voxel %.1f Gy\n",
               center, g->n[0] / 2, g->n[1] / 2, g->n[2] / 2, dmax);
        return;
    }
    NsJson j;
    ns_json_init(&j, stdout, 2);
    ns_json_begin_object(&j);
    ns_json_key(&j, "dose_ms");
    ns_json_begin_object(&j);
    ns_json_key(&j, "median");
    ns_json_number(&j, med);
    ns_json_key(&j, "p95");
    ns_json_number(&j, p95);
    ns_json_key(&j, "min");
    ns_json_number(&j, ms[0]);
    ns_json_key(&j, "max");
    ns_json_number(&j, ms[repeat - 1]);
    ns_json_end_object(&j);
    ns_json_key(&j, "cpu_ms");
    ns_json_begin_object(&j);
    ns_json_key(&j, "median");
    ns_json_number(&j, cpu_med);
    ns_json_end_object(&j);
    ns_json_key(&j, "repeat");
    ns_json_int(&j, repeat);
    ns_json_key(&j, "seeds");
    ns_json_int(&j, seeds);
    ns_json_key(&j, "voxels");
    ns_json_int(&j, voxels);
    ns_json_key(&j, "spacing_mm");
    ns_json_number(&j, g->spacing * 1e3);
    ns_json_key(&j, "threads");
    ns_json_int(&j, threads);
    ns_json_key(&j, "center_gy");
    ns_json_number(&j, center);
    ns_json_key(&j, "max_gy");
    ns_json_number(&j, dmax);
    ns_json_end_object(&j);
    fputc('\n', stdout);
}

int ns_bench_dose(int argc, char **argv)
{
    int repeat = 9, threads = 1;
    bool json = false;
    for (int a = 1; a < argc; a++) {
        if (strcmp(argv[a], "--dose") == 0)
            continue;
        if (strcmp(argv[a], "--json") == 0) {
            json = true;
        } else if (strcmp(argv[a], "--repeat") == 0) {
            if (parse_int("--repeat", a + 1 < argc ? argv[++a] : NULL, 1, DOSE_REPEAT_MAX, &repeat))
                return 2;
        } else if (strcmp(argv[a], "--threads") == 0) {
            if (parse_int("--threads", a + 1 < argc ? argv[++a] : NULL, 1, 64, &threads))
                return 2;
        } else if (strcmp(argv[a], "--help") == 0 || strcmp(argv[a], "-h") == 0) {
            fputs(usage, stdout);
            return 0;
        } else {
            fprintf(stderr, "needlesim: bench --dose: unknown argument '%s'\n%s", argv[a], usage);
            return 2;
        }
    }
    char err[512];
    NsTg43Source src;
    if (ns_tg43_load_6711(&src, err, sizeof err)) {
        fprintf(stderr, "needlesim: bench --dose: %s\n", err);
        return 1;
    }
    NsDoseSeed seeds[IMPLANT_SEEDS];
    int n = implant(seeds);
    const double lo[3] = {-0.02, -0.02, -0.02}, hi[3] = {0.02, 0.02, 0.02};
    double *ms = malloc(2 * (size_t)repeat * sizeof *ms), *cpu = ms + repeat;
    if (!ms) {
        fputs("needlesim: bench --dose: out of memory\n", stderr);
        return 1;
    }
    NsDoseGrid g = {0};
    for (int k = 0; k < repeat; k++) {
        ns_dose_grid_free(&g);
        double t0 = now_ms(CLOCK_MONOTONIC), c0 = now_ms(CLOCK_PROCESS_CPUTIME_ID);
        if (ns_dose_grid(&src, seeds, n, lo, hi, 1e-3, threads, &g, err, sizeof err)) {
            fprintf(stderr, "needlesim: bench --dose: %s\n", err);
            free(ms);
            return 1;
        }
        ms[k] = now_ms(CLOCK_MONOTONIC) - t0;
        cpu[k] = now_ms(CLOCK_PROCESS_CPUTIME_ID) - c0;
    }
    qsort(ms, (size_t)repeat, sizeof *ms, cmp_double);
    qsort(cpu, (size_t)repeat, sizeof *cpu, cmp_double);
    print_result(json, ms, cpu, repeat, threads, &g, n);
    ns_dose_grid_free(&g);
    free(ms);
    return 0;
}
