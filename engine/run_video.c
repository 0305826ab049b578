/* An authored video's cues (run_video.h, docs/rendering.md "Authored videos"). */
#include "run_video.h"

#include <lauxlib.h>
#include <lua.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "run_render.h"
#include "scene.h"

/* The latest cue of kind k in force at t (t0 <= t; captions and slow motion also t < t1). */
static const NsRunCue *latest(const NsRunCues *c, int k, double t, bool until_t1)
{
    const NsRunCue *best = NULL;
    for (int i = 0; i < c->n; i++) {
        const NsRunCue *q = &c->cue[i];
        if (q->kind == k && q->t0 <= t && (!until_t1 || t < q->t1))
            best = q;
    }
    return best;
}

const char *ns_run_video_caption(const NsRunCues *c, double t)
{
    const NsRunCue *q = latest(c, NS_CUE_CAPTION, t, true);
    return q ? q->text : NULL;
}

double ns_run_video_slow(const NsRunCues *c, double t)
{
    const NsRunCue *q = latest(c, NS_CUE_SLOW, t, true);
    return q ? q->factor : 1.0;
}

/* The camera's zoom and orbit at t (1 and 0 before any camera cue). */
static void camera_at(const NsRunCues *c, double t, double *zoom, double *orbit)
{
    const NsRunCue *q = latest(c, NS_CUE_CAMERA, t, false);
    *zoom = 1.0;
    *orbit = 0.0;
    if (!q)
        return;
    double s = q->t1 > q->t0 ? fmin(1.0, (t - q->t0) / (q->t1 - q->t0)) : 1.0;
    *zoom = q->zoom[0] + s * (q->zoom[1] - q->zoom[0]);
    *orbit = q->orbit[0] + s * (q->orbit[1] - q->orbit[0]);
}

void ns_run_video_camera(const NsRunCues *c, double t, const double tip[3], NsSceneInput *in,
                         int *views, int *nviews)
{
    double zoom, orbit;
    camera_at(c, t, &zoom, &orbit);
    in->orbit_deg = orbit;
    if (zoom != 1.0) { /* the box 1/zoom the size, its centre moved towards the tip */
        double k = 1.0 - 1.0 / zoom;
        for (int i = 0; i < 3; i++) {
            double lo = in->bounds[i], hi = in->bounds[3 + i], half = 0.5 * (hi - lo) / zoom;
            double m = 0.5 * (lo + hi) + k * (tip[i] - 0.5 * (lo + hi));
            in->bounds[i] = m - half;
            in->bounds[3 + i] = m + half;
        }
    }
    for (int i = c->n - 1; i >= 0; i--) {
        const NsRunCue *q = &c->cue[i];
        if (q->kind == NS_CUE_CAMERA && q->t0 <= t && q->nviews > 0) {
            memcpy(views, q->views, sizeof q->views);
            *nviews = q->nviews;
            break;
        }
    }
}

void ns_run_video_free(NsRunCues *c)
{
    free(c->cue);
    memset(c, 0, sizeof *c);
}

/* ---- taking the queue (inside the script's protected call) ---- */

typedef struct Take {
    NsRunCues *c;
    NsRunRender *rr; /* or NULL */
    lua_State *L;
    int item, index; /* the cue's table on the stack, its place in the queue */
} Take;

static int take_error(const Take *k, const char *field, const char *what)
{
    return luaL_error(k->L, "sim.control.video[%d].%s %s", k->index, field, what);
}

/* A number field in [lo, hi], else dflt when absent and optional. */
static double take_number(const Take *k, const char *field, double lo, double hi, bool optional,
                          double dflt)
{
    lua_pushstring(k->L, field);
    int ty = lua_rawget(k->L, k->item);
    double v = lua_tonumber(k->L, -1);
    lua_pop(k->L, 1);
    if (ty == LUA_TNIL && optional)
        return dflt;
    if (ty != LUA_TNUMBER || !(v >= lo && v <= hi)) {
        char buf[96];
        snprintf(buf, sizeof buf, "must be a number in [%g, %g]", lo, hi);
        take_error(k, field, buf);
    }
    return v;
}

/* A text field (no NUL, at most NS_LIMIT_VIDEO_TEXT bytes) into out; "" when absent and
 * optional. */
static void take_text(const Take *k, const char *field, bool optional, char *out)
{
    lua_pushstring(k->L, field);
    int ty = lua_rawget(k->L, k->item);
    size_t n = 0;
    const char *s = ty == LUA_TSTRING ? lua_tolstring(k->L, -1, &n) : NULL;
    if (ty == LUA_TNIL && optional) {
        out[0] = '\0';
    } else if (!s || n == 0 || n > NS_LIMIT_VIDEO_TEXT || strlen(s) != n) {
        char buf[96];
        snprintf(buf, sizeof buf, "must be a non-empty string of at most %d bytes without NUL",
                 NS_LIMIT_VIDEO_TEXT);
        take_error(k, field, buf);
    } else {
        memcpy(out, s, n + 1);
    }
    lua_pop(k->L, 1);
}

/* camera: `view` (a name) or `views` (a list of up to three names). */
static void take_views(const Take *k, NsRunCue *q)
{
    lua_State *L = k->L;
    q->nviews = 0;
    lua_pushstring(L, "view");
    int ty = lua_rawget(L, k->item);
    if (ty == LUA_TSTRING) {
        int v = ns_view_parse(lua_tostring(L, -1));
        if (v < 0)
            take_error(k, "view", "must be \"side\", \"top\", \"axis\", \"cutaway3d\" or \"trus\"");
        q->views[q->nviews++] = v;
    } else if (ty != LUA_TNIL) {
        take_error(k, "view", "must be \"side\", \"top\", \"axis\", \"cutaway3d\" or \"trus\"");
    }
    lua_pop(L, 1);
    lua_pushstring(L, "views");
    ty = lua_rawget(L, k->item);
    if (ty == LUA_TTABLE && q->nviews == 0) {
        for (int i = 1; i <= 4; i++) {
            int et = lua_rawgeti(L, -1, i);
            int v = et == LUA_TSTRING ? ns_view_parse(lua_tostring(L, -1)) : -1;
            lua_pop(L, 1);
            if (et == LUA_TNIL && i > 1)
                break;
            if (v < 0 || i > 3)
                take_error(k, "views",
                           "must list one to three of \"side\", \"top\", \"axis\", \"cutaway3d\", "
                           "\"trus\"");
            q->views[q->nviews++] = v;
        }
    } else if (ty != LUA_TNIL) {
        take_error(k, "views", "must be a list of view names (and not beside `view`)");
    }
    lua_pop(L, 1);
}

static void push_cue(const Take *k, NsRunCues *c, const NsRunCue *q)
{
    if (c->n == c->cap) {
        int cap = c->cap ? 2 * c->cap : 16;
        NsRunCue *p = realloc(c->cue, (size_t)cap * sizeof *p);
        if (!p)
            luaL_error(k->L, "needlesim: out of memory");
        c->cue = p;
        c->cap = cap;
    }
    c->cue[c->n++] = *q;
}

/* One cue: checked, then kept or acted on. */
static void take_one(const Take *k, double t, bool apply)
{
    NsRunCues *c = k->c;
    NsRunRender *rr = k->rr;
    lua_pushstring(k->L, "kind");
    lua_rawget(k->L, k->item);
    const char *kind = lua_type(k->L, -1) == LUA_TSTRING ? lua_tostring(k->L, -1) : "";
    static const char *const kinds[] = {"caption", "chapter", "slow_motion", "camera", "card"};
    int which = -1;
    for (int i = 0; i < 5; i++)
        if (strcmp(kind, kinds[i]) == 0)
            which = i;
    lua_pop(k->L, 1);
    if (which < 0)
        take_error(k, "kind",
                   "must be \"caption\", \"chapter\", \"slow_motion\", \"camera\" or \"card\"");
    NsRunCue q;
    memset(&q, 0, sizeof q);
    q.t0 = t;
    char title[NS_LIMIT_VIDEO_TEXT + 1];
    char err[256] = "";
    int rc = 0;
    switch (which) {
    case 0:
        q.kind = NS_CUE_CAPTION;
        take_text(k, "text", false, q.text);
        q.t1 = t + take_number(k, "duration", 1e-3, NS_LIMIT_VIDEO_DURATION, false, 0.0);
        if (apply)
            push_cue(k, c, &q);
        break;
    case 1:
        take_text(k, "title", false, title);
        if (apply && rr)
            rc = ns_run_render_chapter(rr, title, err, sizeof err);
        break;
    case 2:
        q.kind = NS_CUE_SLOW;
        q.factor = take_number(k, "factor", 1.0, NS_LIMIT_VIDEO_SLOW, false, 0.0);
        q.t1 = t + take_number(k, "duration", 1e-3, NS_LIMIT_VIDEO_DURATION, false, 0.0);
        if (apply)
            push_cue(k, c, &q);
        break;
    case 3: {
        q.kind = NS_CUE_CAMERA;
        double zoom, orbit;
        camera_at(c, t, &zoom, &orbit);
        q.zoom[0] = zoom;
        q.orbit[0] = orbit;
        q.zoom[1] =
            take_number(k, "zoom", 1.0 / NS_LIMIT_VIDEO_ZOOM, NS_LIMIT_VIDEO_ZOOM, true, zoom);
        q.orbit[1] =
            orbit + take_number(k, "orbit", -NS_LIMIT_VIDEO_ORBIT, NS_LIMIT_VIDEO_ORBIT, true, 0.0);
        q.t1 = t + take_number(k, "duration", 0.0, NS_LIMIT_VIDEO_DURATION, true, 0.0);
        take_views(k, &q);
        if (apply)
            push_cue(k, c, &q);
        break;
    }
    default: {
        take_text(k, "title", false, title);
        take_text(k, "text", true, q.text);
        double d = take_number(k, "duration", 0.1, NS_LIMIT_VIDEO_CARD_S, true, 3.0);
        if (apply && rr)
            rc = ns_run_render_card(rr, title, q.text, lround(d * rr->o.fps), err, sizeof err);
    }
    }
    if (rc)
        luaL_error(k->L, "needlesim: %s", err);
}

void ns_run_video_take(NsRunCues *c, NsRunRender *rr, lua_State *L, int ci, double t, bool apply)
{
    lua_pushstring(L, "video");
    int ty = lua_rawget(L, ci);
    if (ty == LUA_TNIL) {
        lua_pop(L, 1);
        return;
    }
    if (ty != LUA_TTABLE)
        luaL_error(L, "sim.control.video must be a list of cues");
    int list = lua_gettop(L);
    for (int i = 1;; i++) {
        int et = lua_rawgeti(L, list, i);
        if (et == LUA_TNIL) {
            lua_pop(L, 1);
            break;
        }
        if (et != LUA_TTABLE)
            luaL_error(L, "sim.control.video[%d] must be a table", i);
        if (++c->taken > NS_LIMIT_VIDEO_CUES)
            luaL_error(L, "more than %d video cues in a run", NS_LIMIT_VIDEO_CUES);
        Take k = {.c = c, .rr = rr, .L = L, .item = lua_gettop(L), .index = i};
        take_one(&k, t, apply);
        lua_pop(L, 1);
    }
    lua_pop(L, 1);
    lua_pushstring(L, "video");
    lua_pushnil(L);
    lua_rawset(L, ci);
}
