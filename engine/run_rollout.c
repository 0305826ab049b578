/* `sim.planner.rollout{length, speed}`: the curvature the simulator itself gives the needle from
 * where it is now (docs/planning.md, "Rollouts in the simulator"). The world (tissue, needle,
 * their coupling) is copied in memory (sim/snapshot.h), the copy is stepped with the needle
 * inserted at `speed` and the bevel held, and the tip's path is fitted; the run's own world is
 * not touched (the copy steps from the same bytes to the same states: tests/test_snapshot.c).
 * The planner then predicts with that curvature instead of the kinematic model's (paper §5: the
 * simulator as the planner's model). A rollout reads the world at its tick, so a run that
 * writes or resumes a checkpoint, whose script is replayed against recorded ticks, refuses it. */
#include <lauxlib.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"
#include "ns_limits.h"
#include "run.h"
#include "snapshot.h"
#include "step.h"

#define ROLLOUT_LENGTH_MIN  1e-3   /* [m] */
#define ROLLOUT_LENGTH_MAX  0.1    /* [m] (act.steer's replan_every at most) */
#define ROLLOUT_STEPS_MIN   3      /* the fit's parabola needs three points past the start */
#define ROLLOUT_STEPS_MAX   5000   /* one rollout's steps */
#define ROLLOUT_STEPS_TOTAL 400000 /* a run's rollout steps in all (a global budget) */

/* The fit of the tip's path: from the start p0 along the tangent t0, the offset towards the
 * bevel b is d(s) = a s + kappa s^2 / 2 in least squares (a takes up the tip edge's lean). */
typedef struct RolloutFit {
    double kappa;     /* towards the bevel [1/m] */
    double out_plane; /* largest offset out of the (t0, b) plane [m] */
    double travel;    /* the tip's distance from its start at the end [m] */
    double tip[3];    /* where it ends [m] */
    int steps;
} RolloutFit;

static void fit(const double *tips, int n, const double t0[3], const double b[3], RolloutFit *f)
{
    double o[3] = {t0[1] * b[2] - t0[2] * b[1], t0[2] * b[0] - t0[0] * b[2],
                   t0[0] * b[1] - t0[1] * b[0]};
    double s11 = 0, s12 = 0, s22 = 0, r1 = 0, r2 = 0;
    f->out_plane = 0.0;
    for (int i = 1; i < n; i++) {
        double d[3] = {tips[3 * i] - tips[0], tips[3 * i + 1] - tips[1], tips[3 * i + 2] - tips[2]};
        double s = d[0] * t0[0] + d[1] * t0[1] + d[2] * t0[2];
        double y = d[0] * b[0] + d[1] * b[1] + d[2] * b[2];
        double e = fabs(d[0] * o[0] + d[1] * o[1] + d[2] * o[2]);
        double g1 = s, g2 = 0.5 * s * s;
        s11 += g1 * g1;
        s12 += g1 * g2;
        s22 += g2 * g2;
        r1 += g1 * y;
        r2 += g2 * y;
        f->out_plane = fmax(f->out_plane, e);
    }
    double det = s11 * s22 - s12 * s12;
    f->kappa = det > 0.0 ? (s11 * r2 - s12 * r1) / det : 0.0;
    const double *e = tips + 3 * (n - 1);
    memcpy(f->tip, e, sizeof f->tip);
    f->travel = sqrt((e[0] - tips[0]) * (e[0] - tips[0]) + (e[1] - tips[1]) * (e[1] - tips[1]) +
                     (e[2] - tips[2]) * (e[2] - tips[2]));
}

/* Steps a copy of the run's world n steps at speed v, the bevel held; the fit of the tip's path
 * into f. 0, or -1 with err (memory, or a step of the copy that failed: its message). */
static int rollout(NsRun *r, double v, int n, RolloutFit *f, char *err, int err_sz)
{
    NsWorldSnapshot snap = {0};
    NsTissue t;
    NsRod rod;
    NsCoupled c;
    memset(&t, 0, sizeof t);
    memset(&rod, 0, sizeof rod);
    memset(&c, 0, sizeof c);
    double *tips = malloc((size_t)(n + 1) * 3 * sizeof *tips);
    int rc = -1, got = 0;
    bool restored = false;
    double t0[3], m1[3], b[3];
    if (!tips) {
        ns_set_err(err, err_sz, "out of memory");
        goto done;
    }
    if (ns_world_snapshot(&r->tissue, &r->rod, &r->c, &snap, err, err_sz))
        goto done;
    restored = true; /* from here the copy is freed, whatever state it is in */
    if (ns_world_restore(&snap, &t, &rod, &c, err, err_sz))
        goto done;
    ns_rod_tip_frame(&rod, t0, m1, b);
    memcpy(tips, rod.x + 3 * (rod.nodes - 1), 3 * sizeof *tips);
    const double vb[3] = {0, 0, 0};
    NsStepControls ctl = ns_step_controls(v, vb, 0.0);
    for (got = 0; got < n; got++) {
        if (ns_step(&c, &ctl, r->spec.dt, NULL) != 0) {
            ns_set_err(err, err_sz, "the rollout's step %d failed: %s", got + 1, c.error);
            goto done;
        }
        memcpy(tips + 3 * (got + 1), rod.x + 3 * (rod.nodes - 1), 3 * sizeof *tips);
    }
    fit(tips, n + 1, t0, b, f);
    f->steps = n;
    rc = 0;
done:
    r->steer.rollout_steps += got;
    if (restored) {
        ns_coupled_free(&c);
        ns_rod_free(&rod);
        ns_tissue_free(&t);
    }
    ns_world_snapshot_free(&snap);
    free(tips);
    return rc;
}

static double field(lua_State *L, const char *key)
{
    lua_getfield(L, 1, key);
    int ok = 0;
    double v = lua_tonumberx(L, -1, &ok);
    lua_pop(L, 1);
    if (!ok || !isfinite(v))
        luaL_error(L, "sim.planner.rollout: '%s' must be a finite number", key);
    return v;
}

/* planner.rollout{length = m, speed = m/s} -> {kappa, out_of_plane, travel, tip, steps} */
int ns_run_l_rollout(lua_State *L)
{
    NsRun *r = lua_touserdata(L, lua_upvalueindex(1));
    luaL_checktype(L, 1, LUA_TTABLE);
    double length = field(L, "length"), v = field(L, "speed");
    char msg[300];
    msg[0] = '\0';
    double steps = fmax(ceil(length / (v * r->spec.dt)), ROLLOUT_STEPS_MIN);
    if (!(length >= ROLLOUT_LENGTH_MIN && length <= ROLLOUT_LENGTH_MAX) ||
        !(v > 0.0 && v <= NS_LIMIT_INSERT_SPEED))
        snprintf(msg, sizeof msg,
                 "sim.planner.rollout: length must be in [%g, %g] m and speed in (0, %g] m/s",
                 ROLLOUT_LENGTH_MIN, ROLLOUT_LENGTH_MAX, NS_LIMIT_INSERT_SPEED);
    else if (r->opt.checkpoint || r->opt.resume)
        snprintf(msg, sizeof msg,
                 "act.steer: rollouts read the world at their tick, and a run that writes or "
                 "resumes a checkpoint replays its script without it (docs/planning.md)");
    else if (steps > ROLLOUT_STEPS_MAX)
        snprintf(msg, sizeof msg,
                 "sim.planner.rollout: %.0f steps (at most %d: a shorter length or a faster "
                 "speed)",
                 steps, ROLLOUT_STEPS_MAX);
    else if (r->steer.rollout_steps + (long)steps > ROLLOUT_STEPS_TOTAL)
        snprintf(msg, sizeof msg, "act.steer: the run's rollouts would exceed %d steps in all",
                 ROLLOUT_STEPS_TOTAL);
    if (msg[0]) /* formatted here: lua_pushfstring knows no %g */
        return luaL_error(L, "%s", msg);
    RolloutFit f = {0};
    char err[512];
    double w0 = ns_wall_s();
    int rc = rollout(r, v, (int)steps, &f, err, (int)sizeof err);
    double ms = 1e3 * (ns_wall_s() - w0);
    if (rc)
        return luaL_error(L, "act.steer: rollout: %s", err);
    r->steer.rollouts++;
    if (ns_series_push(&r->steer.rollout_ms, ms) != 0)
        return luaL_error(L, "needlesim: out of memory");
    lua_createtable(L, 0, 5);
    lua_pushnumber(L, f.kappa);
    lua_setfield(L, -2, "kappa");
    lua_pushnumber(L, f.out_plane);
    lua_setfield(L, -2, "out_of_plane");
    lua_pushnumber(L, f.travel);
    lua_setfield(L, -2, "travel");
    lua_pushinteger(L, f.steps);
    lua_setfield(L, -2, "steps");
    lua_createtable(L, 3, 0);
    for (int k = 0; k < 3; k++) {
        lua_pushnumber(L, f.tip[k]);
        lua_rawseti(L, -2, k + 1);
    }
    lua_setfield(L, -2, "tip");
    return 1;
}
