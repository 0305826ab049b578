/* The live session's HTTP + WebSocket server (civetweb; docs/live.md): GET / (the page),
 * GET /stream.mjpg (MJPEG), WebSocket /ws (frames and state out, controls in), 404 for any
 * other path; nothing is ever read from the file system. Bound to 127.0.0.1 unless told
 * otherwise; bound elsewhere, every request needs ?token=<the session's random token> (401
 * without). The first WebSocket client controls the needle, later ones watch; when the
 * controlling client leaves, the next one to connect takes over. */
#ifndef NS_LIVE_SERVER_H
#define NS_LIVE_SERVER_H

#include <stdbool.h>
#include <stddef.h>

#include "live_session.h"

typedef struct NsLiveServer NsLiveServer;

/* Listens on bind:port (port 0: a free port). A token is made and required unless bind is
 * 127.0.0.1 or localhost. NULL with a message in err. */
NsLiveServer *ns_live_server_start(NsLiveSession *s, const char *bind, int port, char *err,
                                   int err_sz);
/* The port listened on. */
int ns_live_server_port(const NsLiveServer *srv);
/* The URL to open: http://HOST:PORT/ with ?token=... when one is required. */
void ns_live_server_url(const NsLiveServer *srv, char *out, size_t out_sz);
/* Closes every connection and stops the server; frees srv. */
void ns_live_server_stop(NsLiveServer *srv);

#endif
