/* The live session's client-to-server messages (docs/live.md, "Protocol"): one flat JSON object
 * per WebSocket text message, each member a control:
 *
 *     {"insert_speed": m/s}   {"twist_rate": rad/s}   {"twist": rad}
 *     {"base_velocity": [vx, vy, vz]}   {"drop_seed": true}   {"next_needle": true}
 *     {"pause": bool}   {"end": true}   {"views": "cutaway3d,trus"}
 *
 * Every message is untrusted (docs/reliability.md): the parser is a strict subset of JSON (RFC
 * 8259) for exactly these shapes. At most NS_LIMIT_LIVE_MESSAGE_BYTES bytes, one object, known
 * keys only, each once, numbers finite and within sim/ns_limits.h's control limits, nothing
 * nested but base_velocity's array of three numbers; views is 1 to 3 view names (as --layout
 * takes them), or "" for the scenario's own. views changes what the frames show, never the physics,
 * and is not logged. Anything else is an error, and the whole message is ignored: a message is
 * applied in full or not at all.
 */
#ifndef NS_LIVE_PROTOCOL_H
#define NS_LIVE_PROTOCOL_H

#include <stdbool.h>
#include <stddef.h>

enum {
    NS_LIVE_INSERT_SPEED = 1 << 0,
    NS_LIVE_TWIST_RATE = 1 << 1,
    NS_LIVE_TWIST = 1 << 2,
    NS_LIVE_BASE_VELOCITY = 1 << 3,
    NS_LIVE_DROP_SEED = 1 << 4,
    NS_LIVE_NEXT_NEEDLE = 1 << 5,
    NS_LIVE_PAUSE = 1 << 6,
    NS_LIVE_END = 1 << 7,
    NS_LIVE_VIEWS = 1 << 8,
};

typedef struct NsLiveMsg {
    unsigned has;            /* NS_LIVE_* bits: the members present */
    double insert_speed;     /* [m/s], negative retracts */
    double twist_rate;       /* [rad/s] */
    double twist;            /* [rad]: a turn by this angle, signed */
    double base_velocity[3]; /* [m/s] */
    bool drop_seed, next_needle, pause, end;
    int views[3], nviews; /* NsView values side by side */
} NsLiveMsg;

/* Parses one message of n bytes (not NUL-terminated; NUL bytes are an error). Returns 0, or -1
 * with a one-line reason in err (plain text; the caller escapes it into {"error": ...}). */
int ns_live_parse(const char *text, size_t n, NsLiveMsg *m, char *err, int err_sz);

/* {"error": "<msg>"} as one JSON text (msg escaped, invalid UTF-8 replaced) into out; the
 * length, or -1 when it does not fit. */
int ns_live_error_json(const char *msg, char *out, size_t out_sz);

#endif
