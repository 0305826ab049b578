/* needlesim bench --live SCENARIO.lua [--seconds S] [--json] [--threads N] [--set KEY=VALUE]...
 *                                     [--width W --height H] [--fps F] [-o DIR]
 *                                     [--samples N] [--accuracy TIP [--front NAME]]
 *
 * The bars, measured (docs/live.md, "Measuring"): a live session on a free loopback
 * port, driven over a real WebSocket by a synthetic client (civetweb's client API) that
 * follows a fixed control script: insert for 45 % of the time (the speed changes every half
 * second, each change a latency sample), twist for 20 %, drop a seed when the scenario plans
 * seeds, retract slowly, end. Prints the delivered frame rate (frames the client received, per
 * second), the real-time factor, the input latency (control message's arrival to the first
 * frame rendered after the step that applied it), render and encode times, the step time, and
 * the session's state hash. */
#include "commands.h"

#include <civetweb.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "json.h"
#include "live_session.h"
#include "series.h"

static const char usage[] =
    "usage: needlesim bench --live SCENARIO.lua [--seconds S] [--json] [--threads N]\n"
    "                       [--set KEY=VALUE]... [--width W --height H] [--fps F] [-o DIR]\n"
    "                       [--samples N] [--accuracy TIP [--front NAME]]\n";

typedef struct Bench {
    double seconds;
    int port;
    pthread_t thread;
    bool started;
    /* the client's side (the civetweb client thread writes, the bench thread reads at the end) */
    pthread_mutex_t mu;
    double *arrivals; /* frame arrival times [s] */
    long frames, cap;
    atomic_bool closed;
    atomic_int seeds_planned; /* from the state messages (-1: none seen yet) */
    char err[256];
} Bench;

static int on_data(struct mg_connection *conn, int bits, char *data, size_t n, void *ctx)
{
    (void)conn;
    Bench *b = ctx;
    int op = bits & 0x0f;
    if (op == MG_WEBSOCKET_OPCODE_BINARY && n > 2) {
        pthread_mutex_lock(&b->mu);
        if (b->frames == b->cap) {
            long cap = b->cap ? 2 * b->cap : 1024;
            double *a = realloc(b->arrivals, (size_t)cap * sizeof *a);
            if (a) {
                b->arrivals = a;
                b->cap = cap;
            }
        }
        if (b->frames < b->cap)
            b->arrivals[b->frames++] = ns_wall_s();
        pthread_mutex_unlock(&b->mu);
    } else if (op == MG_WEBSOCKET_OPCODE_TEXT && atomic_load(&b->seeds_planned) < 0) {
        char text[4096];
        snprintf(text, sizeof text, "%.*s", (int)(n < sizeof text - 1 ? n : sizeof text - 1), data);
        const char *p = strstr(text, "\"seeds_planned\":");
        if (p)
            atomic_store(&b->seeds_planned, atoi(p + 16));
    }
    return op != MG_WEBSOCKET_OPCODE_CONNECTION_CLOSE;
}

static void on_close(const struct mg_connection *conn, void *ctx)
{
    (void)conn;
    atomic_store(&((Bench *)ctx)->closed, true);
}

static void nap(double s)
{
    struct timespec ts = {(time_t)s, (long)((s - floor(s)) * 1e9)};
    nanosleep(&ts, NULL);
}

static void say(struct mg_connection *c, const char *text)
{
    mg_websocket_client_write(c, MG_WEBSOCKET_OPCODE_TEXT, text, strlen(text));
}

/* The control script (the header's). */
static void *client_main(void *arg)
{
    Bench *b = arg;
    char ebuf[256] = "";
    struct mg_connection *c = mg_connect_websocket_client(
        "127.0.0.1", b->port, 0, ebuf, sizeof ebuf, "/ws", NULL, on_data, on_close, b);
    if (!c) {
        snprintf(b->err, sizeof b->err, "the client cannot connect: %s", ebuf);
        kill(getpid(), SIGTERM); /* nobody else would end the session */
        return NULL;
    }
    double T = b->seconds, t0 = ns_wall_s();
    for (int k = 0; !atomic_load(&b->closed) && ns_wall_s() - t0 < 0.45 * T; k++) {
        say(c, k % 2 ? "{\"insert_speed\": 0.004}" : "{\"insert_speed\": 0.005}");
        nap(0.5);
    }
    say(c, "{\"insert_speed\": 0, \"twist_rate\": 3.14159}");
    nap(0.2 * T);
    say(c, "{\"twist_rate\": 0}");
    if (atomic_load(&b->seeds_planned) > 0)
        say(c, "{\"drop_seed\": true}");
    for (int k = 0; !atomic_load(&b->closed) && ns_wall_s() - t0 < 0.95 * T; k++) {
        say(c, k % 2 ? "{\"insert_speed\": -0.002}" : "{\"insert_speed\": -0.001}");
        nap(0.5);
    }
    say(c, "{\"end\": true}");
    for (int i = 0; i < 600 && !atomic_load(&b->closed); i++)
        nap(0.1);
    mg_close_connection(c);
    return NULL;
}

static void hook(const char *url, int port, void *ctx)
{
    (void)url;
    Bench *b = ctx;
    b->port = port;
    b->started = pthread_create(&b->thread, NULL, client_main, b) == 0;
}

/* Frames the client received per second, over whole seconds from the first frame. */
static void delivered(const Bench *b, NsSeries *fps)
{
    if (b->frames < 2)
        return;
    double w0 = b->arrivals[0];
    long n = 0;
    for (long i = 1; i < b->frames; i++) {
        n++;
        if (b->arrivals[i] - w0 >= 1.0) {
            ns_series_push(fps, (double)n / (b->arrivals[i] - w0));
            w0 = b->arrivals[i];
            n = 0;
        }
    }
}

static void print_json(const Bench *b, const NsLiveRunResult *res, const NsSeries *fps)
{
    const NsLiveFigures *f = &res->fig;
    NsJson j;
    ns_json_init(&j, stdout, 1);
    ns_json_begin_object(&j);
    const char *keys[] = {"delivered_fps_median",
                          "delivered_fps_p5",
                          "rtf_median",
                          "rtf_min",
                          "input_latency_ms_median",
                          "input_latency_ms_p95",
                          "render_ms",
                          "encode_ms",
                          "step_ms",
                          "snapshot_ms",
                          "session_fps_median",
                          "scene_ms",
                          "gl_ms",
                          "step_cpu_ms",
                          "frame_cpu_ms"};
    double vals[] = {ns_series_quantile(fps, 0.5),
                     ns_series_quantile(fps, 0.05),
                     f->rtf_median,
                     f->rtf_min,
                     f->latency_median,
                     f->latency_p95,
                     f->render_ms,
                     f->encode_ms,
                     f->step_ms,
                     f->snapshot_ms,
                     f->fps_median,
                     f->scene_ms,
                     f->gl_ms,
                     f->step_cpu_ms,
                     f->frame_cpu_ms};
    for (size_t k = 0; k < sizeof vals / sizeof vals[0]; k++) {
        ns_json_key(&j, keys[k]);
        ns_json_number(&j, vals[k]);
    }
    ns_json_key(&j, "frames_received");
    ns_json_int(&j, b->frames);
    ns_json_key(&j, "latency_samples");
    ns_json_int(&j, f->latency_samples);
    ns_json_key(&j, "steps");
    ns_json_int(&j, res->steps);
    ns_json_key(&j, "sim_s");
    ns_json_number(&j, res->sim_s);
    ns_json_key(&j, "wall_s");
    ns_json_number(&j, res->wall_s);
    ns_json_key(&j, "score");
    ns_json_number(&j, res->score);
    char h[32];
    snprintf(h, sizeof h, "%016llx", (unsigned long long)res->hash);
    ns_json_key(&j, "state_hash");
    ns_json_string(&j, h);
    ns_json_end_object(&j);
}

int ns_bench_live(int argc, char **argv)
{
    const char *largv[96] = {"live", NULL, "--port", "0", "--quiet"};
    int largc = 5;
    bool json = false, out = false;
    Bench b;
    memset(&b, 0, sizeof b);
    b.seconds = 20.0;
    atomic_store(&b.seeds_planned, -1);
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (strcmp(a, "--live") == 0) {
            continue;
        } else if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            fputs(usage, stdout);
            return 0;
        } else if (strcmp(a, "--json") == 0) {
            json = true;
        } else if (strcmp(a, "--seconds") == 0) {
            char *end;
            b.seconds = i + 1 < argc ? strtod(argv[i + 1], &end) : 0.0;
            if (i + 1 >= argc || *end || !(b.seconds >= 2.0 && b.seconds <= 3600.0)) {
                fprintf(stderr,
                        "needlesim bench --live: --seconds: expected a number in [2, "
                        "3600]\n%s",
                        usage);
                return 2;
            }
            i++;
        } else if (a[0] != '-' && !largv[1]) {
            largv[1] = a;
        } else if (largc < 92) { /* the live command's own options, checked there */
            out |= strcmp(a, "-o") == 0;
            largv[largc++] = a;
        }
    }
    if (!largv[1]) {
        fprintf(stderr, "needlesim bench --live: missing SCENARIO.lua\n%s", usage);
        return 2;
    }
    if (!out) {
        largv[largc++] = "-o";
        largv[largc++] = "needlesim-bench-live";
    }
    pthread_mutex_init(&b.mu, NULL);
    NsLiveRunResult res;
    memset(&res, 0, sizeof res);
    int rc = ns_live_run(largc, (char **)largv, (NsLiveHook){hook, &b}, &res);
    if (b.started)
        pthread_join(b.thread, NULL);
    NsSeries fps = {0};
    delivered(&b, &fps);
    if (rc == 0 && b.err[0]) {
        fprintf(stderr, "needlesim bench --live: %s\n", b.err);
        rc = 1;
    }
    if (rc == 0 && json) {
        print_json(&b, &res, &fps);
    } else if (rc == 0) {
        const NsLiveFigures *f = &res.fig;
        printf("%s: %.1f s simulated in %.1f s wall (%ld steps), a synthetic client over "
               "WebSocket\n",
               largv[1], res.sim_s, res.wall_s, res.steps);
        printf("delivered fps      %6.1f median, %6.1f p5 (%ld frames received)\n",
               ns_series_quantile(&fps, 0.5), ns_series_quantile(&fps, 0.05), b.frames);
        printf("real-time factor   %6.3f median, %6.3f min\n", f->rtf_median, f->rtf_min);
        printf("input latency      %6.1f ms median, %6.1f ms p95 (%ld messages)\n",
               f->latency_median, f->latency_p95, f->latency_samples);
        printf("where the time goes: step %.2f ms (median; dt %.4g s), render %.1f ms (scene "
               "%.1f, OpenGL %.1f), encode %.1f ms, state copy %.3f ms a frame\n",
               f->step_ms, res.steps ? res.sim_s / (double)res.steps : 0.0, f->render_ms,
               f->scene_ms, f->gl_ms, f->encode_ms, f->snapshot_ms);
        printf("CPU time: a step %.2f ms on the solver's thread, a frame %.1f ms on the render "
               "thread (without llvmpipe's rasterizer threads, if any)\n",
               f->step_cpu_ms, f->frame_cpu_ms);
        printf("score %.1f; state hash %016llx\n", res.score, (unsigned long long)res.hash);
    }
    free(fps.v);
    free(b.arrivals);
    pthread_mutex_destroy(&b.mu);
    return rc;
}
