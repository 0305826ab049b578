/* The live session's server (live_server.h) on civetweb. Its threads copy bytes: control
 * messages go to the session (ns_live_session_control), finished frames come from it
 * (ns_live_session_frame). Each WebSocket client has a sender thread that writes the newest
 * frame when there is one (a slow client skips frames, it never holds others up). */
#include "live_server.h"

#include <civetweb.h>
#include <dlfcn.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/random.h>
#include <time.h>

#include "err.h"
#include "live_protocol.h"
#include "ns_limits.h"
#include "series.h"

/* Debian's civetweb starts its threads with a stack of 100 KiB fixed at its build
 * (USE_STACK_SIZE), and glibc takes the process's static TLS out of a thread's stack: OpenBLAS
 * (60 KiB) and METIS (29 KiB) leave civetweb ~10 KiB, and its first getnameinfo overflows.
 * This definition, which the dynamic linker binds civetweb's calls to, raises any stack asked
 * for to NS_MIN_THREAD_STACK; larger requests pass unchanged. */
#define NS_MIN_THREAD_STACK ((size_t)1 << 20)

int pthread_attr_setstacksize(pthread_attr_t *attr, size_t size)
{
    static int (*real)(pthread_attr_t *, size_t);
    if (!real)
        *(void **)&real = dlsym(RTLD_NEXT, "pthread_attr_setstacksize");
    if (!real)
        return 22; /* EINVAL */
    return real(attr, size < NS_MIN_THREAD_STACK ? NS_MIN_THREAD_STACK : size);
}

/* How long the server waits, at the session's end, for the clients to be sent the end [s]. */
#define NS_LIVE_DRAIN_S 3.0

extern const char ns_live_page[];
extern const size_t ns_live_page_size;

typedef struct Client {
    struct mg_connection *conn;
    NsLiveServer *srv;
    pthread_t sender;
    bool starting;       /* (srv->mu) published, its sender not yet started */
    bool sender_started; /* (srv->mu while starting) */
    atomic_bool closing;
    atomic_bool controller;
    atomic_bool done; /* the sender has returned (after the end, when the session is over) */
} Client;

struct NsLiveServer {
    struct mg_context *ctx;
    NsLiveSession *s;
    pthread_mutex_t mu;
    Client *clients[NS_LIMIT_LIVE_CLIENTS]; /* (mu) */
    int nclients, viewers;                  /* (mu) */
    Client *controller;                     /* (mu) */
    bool need_token;
    char token[33];
    char host[64];
    int port;
};

/* ---- requests ---- */

static const char *path_of(const struct mg_request_info *ri)
{
    return ri->local_uri_raw ? ri->local_uri_raw : ri->request_uri ? ri->request_uri : "";
}

/* Compares in time independent of where they differ. */
static bool same_secret(const char *a, size_t an, const char *b, size_t bn)
{
    unsigned char d = an != bn;
    for (size_t i = 0; i < an && i < bn; i++)
        d |= (unsigned char)(a[i] ^ b[i]);
    return d == 0;
}

/* ?token=... in the query string matches the session's. */
static bool token_ok(const NsLiveServer *srv, const struct mg_request_info *ri)
{
    if (!srv->need_token)
        return true;
    const char *q = ri->query_string;
    for (const char *p = q; p && *p;) {
        const char *amp = strchr(p, '&');
        size_t n = amp ? (size_t)(amp - p) : strlen(p);
        if (n >= 6 && strncmp(p, "token=", 6) == 0 &&
            same_secret(p + 6, n - 6, srv->token, strlen(srv->token)))
            return true;
        p = amp ? amp + 1 : NULL;
    }
    return false;
}

static void reply(struct mg_connection *conn, int code, const char *status, const char *text)
{
    mg_printf(conn,
              "HTTP/1.1 %d %s\r\nContent-Type: text/plain; charset=utf-8\r\nContent-Length: "
              "%zu\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n%s",
              code, status, strlen(text), text);
}

/* Every request, WebSocket handshakes included, passes here first. */
static int auth_handler(struct mg_connection *conn, void *cb)
{
    NsLiveServer *srv = cb;
    const struct mg_request_info *ri = mg_get_request_info(conn);
    if (token_ok(srv, ri))
        return 1;
    reply(conn, 401, "Unauthorized", "401: this session needs ?token=... (printed with its URL)\n");
    return 0;
}

/* A handler is called for its path and every path below it: anything but the path itself is
 * 404, anything but GET 405. Returns 0 when the request is for `path`, else the status sent. */
static int route(struct mg_connection *conn, const char *path)
{
    const struct mg_request_info *ri = mg_get_request_info(conn);
    if (strcmp(path_of(ri), path) != 0) {
        reply(conn, 404, "Not Found", "404: not found\n");
        return 404;
    }
    if (strcmp(ri->request_method, "GET") != 0) {
        reply(conn, 405, "Method Not Allowed", "405: GET only\n");
        return 405;
    }
    return 0;
}

static int page_handler(struct mg_connection *conn, void *cb)
{
    (void)cb;
    int status = route(conn, "/");
    if (status)
        return status;
    mg_printf(conn,
              "HTTP/1.1 200 OK\r\nContent-Type: text/html; charset=utf-8\r\nContent-Length: "
              "%zu\r\nCache-Control: no-store\r\nX-Content-Type-Options: nosniff\r\n"
              "X-Frame-Options: DENY\r\nConnection: close\r\n\r\n",
              ns_live_page_size);
    mg_write(conn, ns_live_page, ns_live_page_size);
    return 200;
}

/* GET /stream.mjpg: the frames as multipart/x-mixed-replace, until the session ends or the
 * viewer leaves. */
static int mjpeg_handler(struct mg_connection *conn, void *cb)
{
    NsLiveServer *srv = cb;
    int status = route(conn, "/stream.mjpg");
    if (status)
        return status;
    pthread_mutex_lock(&srv->mu);
    bool room = srv->viewers < NS_LIMIT_LIVE_VIEWERS;
    srv->viewers += room;
    pthread_mutex_unlock(&srv->mu);
    if (!room) {
        reply(conn, 503, "Service Unavailable", "503: too many viewers\n");
        return 503;
    }
    mg_printf(conn, "HTTP/1.1 200 OK\r\nContent-Type: multipart/x-mixed-replace; "
                    "boundary=nsframe\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n");
    NsLiveBytes jpeg = {0}, json = {0};
    uint64_t seq = 0;
    for (;;) {
        int got = ns_live_session_frame(srv->s, &seq, &jpeg, &json, 500);
        if (got < 0)
            break;
        if (got == 0)
            continue;
        if (mg_printf(conn, "--nsframe\r\nContent-Type: image/jpeg\r\nContent-Length: %zu\r\n\r\n",
                      jpeg.n) <= 0 ||
            mg_write(conn, jpeg.p, jpeg.n) <= 0 || mg_write(conn, "\r\n", 2) <= 0)
            break;
    }
    free(jpeg.p);
    free(json.p);
    pthread_mutex_lock(&srv->mu);
    srv->viewers--;
    pthread_mutex_unlock(&srv->mu);
    return 200;
}

/* ---- WebSocket ---- */

static void send_text(struct mg_connection *conn, const char *text)
{
    mg_websocket_write(conn, MG_WEBSOCKET_OPCODE_TEXT, text, strlen(text));
}

static void send_error(struct mg_connection *conn, const char *msg)
{
    char out[600];
    if (ns_live_error_json(msg, out, sizeof out) > 0)
        send_text(conn, out);
}

/* A browser's handshake must come from this server's own page (Origin = http://Host): another
 * site open in the trainee's browser must not drive the session. Clients that send no Origin
 * (programs) are let in. */
static bool origin_ok(const struct mg_connection *conn)
{
    const char *origin = mg_get_header(conn, "Origin"), *host = mg_get_header(conn, "Host");
    if (!origin)
        return true;
    if (!host || strncmp(origin, "http://", 7) != 0)
        return false;
    return strcmp(origin + 7, host) == 0;
}

static int ws_connect(const struct mg_connection *conn, void *cb)
{
    NsLiveServer *srv = cb;
    if (strcmp(path_of(mg_get_request_info(conn)), "/ws") != 0 || !origin_ok(conn))
        return 1;
    pthread_mutex_lock(&srv->mu);
    bool room = srv->nclients < NS_LIMIT_LIVE_CLIENTS;
    pthread_mutex_unlock(&srv->mu);
    return room ? 0 : 1;
}

/* The client's sender: its role, refusals for the controller, and the newest frames. */
static void *sender_main(void *arg)
{
    Client *c = arg;
    NsLiveBytes jpeg = {0}, json = {0};
    uint64_t seq = 0, notice = 0;
    int role = -1;
    char msg[300];
    /* refusals from before this client connected are not its own */
    while (ns_live_session_notice(c->srv->s, &notice, msg, sizeof msg))
        ;
    while (!atomic_load(&c->closing)) {
        bool ctl = atomic_load(&c->controller);
        if (role != (int)ctl) {
            role = ctl;
            send_text(c->conn, ctl ? "{\"role\": \"control\"}" : "{\"role\": \"watch\"}");
        }
        if (ns_live_session_notice(c->srv->s, &notice, msg, sizeof msg) && ctl)
            send_error(c->conn, msg);
        int got = ns_live_session_frame(c->srv->s, &seq, &jpeg, &json, 100);
        if (got < 0) { /* the session is over: say so and close */
            send_text(c->conn, "{\"ended\": true}");
            mg_websocket_write(c->conn, MG_WEBSOCKET_OPCODE_CONNECTION_CLOSE, "\x03\xe8", 2);
            break;
        }
        if (got == 0)
            continue;
        if (mg_websocket_write(c->conn, MG_WEBSOCKET_OPCODE_BINARY, jpeg.p, jpeg.n) <= 0 ||
            mg_websocket_write(c->conn, MG_WEBSOCKET_OPCODE_TEXT, json.p, json.n) <= 0)
            break;
    }
    free(jpeg.p);
    free(json.p);
    atomic_store(&c->done, true);
    return NULL;
}

static void ws_ready(struct mg_connection *conn, void *cb)
{
    NsLiveServer *srv = cb;
    Client *c = calloc(1, sizeof *c);
    if (!c)
        return;
    c->conn = conn;
    c->srv = srv;
    pthread_mutex_lock(&srv->mu);
    if (srv->nclients == NS_LIMIT_LIVE_CLIENTS) {
        pthread_mutex_unlock(&srv->mu);
        free(c);
        return;
    }
    c->starting = true;
    srv->clients[srv->nclients++] = c;
    if (!srv->controller) {
        srv->controller = c;
        atomic_store(&c->controller, true);
    }
    pthread_mutex_unlock(&srv->mu);
    mg_set_user_connection_data(conn, c);
    ns_live_session_clients(srv->s, 1);
    bool ok = pthread_create(&c->sender, NULL, sender_main, c) == 0;
    if (!ok)
        atomic_store(&c->closing, true); /* no frames; ws_close still cleans up */
    pthread_mutex_lock(&srv->mu);
    c->sender_started = ok;
    c->starting = false;
    pthread_mutex_unlock(&srv->mu);
}

/* A client's message: a control from the controlling client, an error for anything else. */
static int ws_data(struct mg_connection *conn, int bits, char *data, size_t n, void *cb)
{
    NsLiveServer *srv = cb;
    double arrival = ns_wall_s();
    Client *c = mg_get_user_connection_data(conn);
    int op = bits & 0x0f;
    if (op == MG_WEBSOCKET_OPCODE_CONNECTION_CLOSE)
        return 0;
    if (op == MG_WEBSOCKET_OPCODE_PING || op == MG_WEBSOCKET_OPCODE_PONG)
        return 1;
    if (!c)
        return 0;
    if (op != MG_WEBSOCKET_OPCODE_TEXT || !(bits & 0x80)) {
        send_error(conn, op == MG_WEBSOCKET_OPCODE_BINARY
                             ? "binary messages are not accepted: send JSON text"
                             : "fragmented messages are not accepted");
        return 1;
    }
    NsLiveMsg m;
    char err[300];
    if (ns_live_parse(data, n, &m, err, sizeof err)) {
        send_error(conn, err);
        return 1;
    }
    if (!atomic_load(&c->controller)) {
        send_error(conn, "watching: another client controls the session (the first to connect "
                         "controls; when it leaves, the next to connect takes over)");
        return 1;
    }
    (void)srv;
    if (ns_live_session_control(srv->s, &m, arrival, err, sizeof err))
        send_error(conn, err);
    return 1;
}

static void ws_close(const struct mg_connection *conn, void *cb)
{
    NsLiveServer *srv = cb;
    Client *c = mg_get_user_connection_data(conn);
    if (!c)
        return;
    atomic_store(&c->closing, true);
    if (c->sender_started)
        pthread_join(c->sender, NULL);
    pthread_mutex_lock(&srv->mu);
    for (int i = 0; i < srv->nclients; i++)
        if (srv->clients[i] == c) {
            srv->clients[i] = srv->clients[--srv->nclients];
            break;
        }
    if (srv->controller == c)
        srv->controller = NULL; /* the next client to connect takes over */
    pthread_mutex_unlock(&srv->mu);
    ns_live_session_clients(srv->s, -1);
    mg_set_user_connection_data(conn, NULL);
    free(c);
}

/* ---- the server ---- */

static int log_message(const struct mg_connection *conn, const char *message)
{
    (void)conn;
    (void)message;
    return 1; /* civetweb's own log lines stay off stderr */
}

static int make_token(char out[33], char *err, int err_sz)
{
    unsigned char b[16];
    if (getrandom(b, sizeof b, 0) != (ssize_t)sizeof b) {
        ns_set_err(err, err_sz, "cannot make the session's token: getrandom failed");
        return -1;
    }
    for (int i = 0; i < 16; i++)
        snprintf(out + 2 * i, 3, "%02x", b[i]);
    return 0;
}

NsLiveServer *ns_live_server_start(NsLiveSession *s, const char *bind, int port, char *err,
                                   int err_sz)
{
    NsLiveServer *srv = calloc(1, sizeof *srv);
    if (!srv || pthread_mutex_init(&srv->mu, NULL)) {
        free(srv);
        ns_set_err(err, err_sz, "out of memory");
        return NULL;
    }
    srv->s = s;
    bool local = strcmp(bind, "127.0.0.1") == 0 || strcmp(bind, "localhost") == 0;
    srv->need_token = !local;
    snprintf(srv->host, sizeof srv->host, "%s",
             strcmp(bind, "localhost") == 0 ? "127.0.0.1" : bind);
    if (srv->need_token && make_token(srv->token, err, err_sz)) {
        free(srv);
        return NULL;
    }
    char ports[96], threads[16];
    snprintf(ports, sizeof ports, "%s:%d", srv->host, port);
    snprintf(threads, sizeof threads, "%d", NS_LIMIT_LIVE_CLIENTS + NS_LIMIT_LIVE_VIEWERS + 4);
    const char *options[] = {
        "listening_ports",    ports,   "num_threads", threads, "enable_keep_alive", "no",
        "request_timeout_ms", "10000", NULL};
    struct mg_callbacks cbs;
    memset(&cbs, 0, sizeof cbs);
    cbs.log_message = log_message;
    mg_init_library(0);
    srv->ctx = mg_start(&cbs, srv, options);
    if (!srv->ctx) {
        ns_set_err(err, err_sz,
                   "cannot listen on %s:%d (in use, or not an IPv4 address of this machine)",
                   srv->host, port);
        mg_exit_library();
        pthread_mutex_destroy(&srv->mu);
        free(srv);
        return NULL;
    }
    struct mg_server_port sp[4];
    int np = mg_get_server_ports(srv->ctx, 4, sp);
    srv->port = np > 0 ? sp[0].port : port;
    mg_set_auth_handler(srv->ctx, "/", auth_handler, srv);
    mg_set_request_handler(srv->ctx, "/", page_handler, srv);
    mg_set_request_handler(srv->ctx, "/stream.mjpg", mjpeg_handler, srv);
    mg_set_websocket_handler(srv->ctx, "/ws", ws_connect, ws_ready, ws_data, ws_close, srv);
    return srv;
}

int ns_live_server_port(const NsLiveServer *srv)
{
    return srv->port;
}

void ns_live_server_url(const NsLiveServer *srv, char *out, size_t out_sz)
{
    /* bound to every interface: this machine's loopback reaches it */
    const char *host = strcmp(srv->host, "0.0.0.0") == 0 ? "127.0.0.1" : srv->host;
    snprintf(out, out_sz, "http://%s:%d/%s%s", host, srv->port, srv->need_token ? "?token=" : "",
             srv->need_token ? srv->token : "");
}

/* True once every client's sender has returned: after the session is over, each has sent the
 * last frame, {"ended": true} and its close (or found its client gone). */
static bool senders_done(NsLiveServer *srv)
{
    pthread_mutex_lock(&srv->mu);
    bool done = true;
    for (int i = 0; i < srv->nclients; i++) {
        const Client *c = srv->clients[i];
        done = done && !c->starting && (!c->sender_started || atomic_load(&c->done));
    }
    pthread_mutex_unlock(&srv->mu);
    return done;
}

void ns_live_server_stop(NsLiveServer *srv)
{
    if (!srv)
        return;
    /* mg_stop closes the sockets at once: the senders first finish writing the end, for
     * NS_LIVE_DRAIN_S at most (a client that reads nothing cannot hold the exit up). */
    double until = ns_wall_s() + NS_LIVE_DRAIN_S;
    while (!senders_done(srv) && ns_wall_s() < until)
        nanosleep(&(struct timespec){.tv_nsec = 10 * 1000 * 1000}, NULL);
    mg_stop(srv->ctx); /* closes the connections: ws_close joins each sender */
    mg_exit_library();
    pthread_mutex_destroy(&srv->mu);
    free(srv);
}
