/* RRT over arcs: see rrt.h. */
#include "rrt.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"
#include "plan_math.h"
#include "rng.h"

NsRrtParams ns_rrt_default(double kappa, const double lo[3], const double hi[3])
{
    NsRrtParams p;
    memset(&p, 0, sizeof p);
    p.kappa = kappa;
    p.clearance = 1e-3;
    p.tolerance = 1e-3;
    p.step = 5e-3;
    p.check_step = 0.25e-3;
    memcpy(p.lo, lo, sizeof p.lo);
    memcpy(p.hi, hi, sizeof p.hi);
    p.goal_bias = 0.1;
    p.max_nodes = 20000;
    p.max_iterations = 100000;
    p.seed = 1;
    return p;
}

typedef struct Node {
    NsPlanPose pose;
    int parent;
    NsPlanAction action; /* from the parent */
    double depth;        /* insertion from the start [m] */
} Node;

typedef struct Rrt {
    const NsRrtParams *prm;
    const NsPlanObstacle *obs;
    int nobs;
    Node *nodes;
    int count;
    NsRrtStats st;
} Rrt;

/* The arc from pose through q: the twist that puts q in the bevel's plane, the duty cycle
 * whose curvature reaches it and the arc length to it. False when q is not ahead or needs
 * more than kappa. */
static bool arc_to(const NsPlanPose *pose, const double q[3], double kappa, NsPlanAction *a)
{
    double d[3], m1[3];
    pm_sub(q, pose->p, d);
    ns_plan_pose_m1(pose, m1);
    double fwd = pm_dot(d, pose->t), x = pm_dot(d, pose->m2), y = pm_dot(d, m1);
    double b = sqrt(x * x + y * y), r2 = fwd * fwd + b * b;
    if (!(fwd > 0.0))
        return false;
    double need = 2.0 * b / r2;
    if (need > kappa * (1.0 + 1e-12))
        return false;
    need = fmin(need, kappa);
    double th = 2.0 * atan2(b, fwd);               /* the turn of the tangent along the arc */
    a->twist = b > 0.0 ? atan2(-y, x) + 0.0 : 0.0; /* + 0.0: no -0 in the output */
    a->duty = 1.0 - need / kappa;
    a->rate = 0.0;
    a->length = need > 0.0 ? th / need : fwd;
    return true;
}

static bool inside(const NsRrtParams *prm, const double p[3])
{
    const double slack = 1e-9; /* [m]: the entry may lie on the workspace's face */
    for (int i = 0; i < 3; i++)
        if (!(p[i] >= prm->lo[i] - slack && p[i] <= prm->hi[i] + slack))
            return false;
    return true;
}

/* Every check_step along the action from pose: clear of obstacles and inside. */
static bool clear(const Rrt *r, const NsPlanPose *pose, const NsPlanAction *a)
{
    NsPlanPose p = *pose;
    ns_plan_twist(&p, a->twist);
    double k = ns_plan_kappa_eff(r->prm->kappa, a->duty);
    int n = (int)ceil(a->length / r->prm->check_step);
    /* a signed distance changes at most 1 m per m: between two checks h apart the distance
     * dips at most h / 2 below the smaller of the two, so the check asks for that much more */
    double need = r->prm->clearance + 0.5 * a->length / (n > 0 ? n : 1);
    for (int i = 1; i <= n; i++) {
        NsPlanPose q;
        ns_plan_advance(&p, k, 0.0, a->length * i / n, &q);
        if (!inside(r->prm, q.p) ||
            !(ns_plan_obstacles_distance(r->obs, r->nobs, q.p, NULL) >= need))
            return false;
    }
    return true;
}

/* The node whose arc to q is shortest (-1: none reaches it). */
static int nearest(const Rrt *r, const double q[3])
{
    int best = -1;
    double bl = INFINITY;
    for (int i = 0; i < r->count; i++) {
        NsPlanAction a;
        if (arc_to(&r->nodes[i].pose, q, r->prm->kappa, &a) && a.length < bl) {
            bl = a.length;
            best = i;
        }
    }
    return best;
}

/* Adds the node at the end of action a from node `from` if it is clear; its index or -1. */
static int add(Rrt *r, int from, const NsPlanAction *a)
{
    const Node *f = &r->nodes[from];
    double depth = f->depth + a->length;
    if ((r->prm->max_length > 0.0 && depth > r->prm->max_length) || !clear(r, &f->pose, a)) {
        r->st.rejected++;
        return -1;
    }
    Node n;
    if (!ns_plan_action_apply(&f->pose, a, r->prm->kappa, &n.pose))
        return -1;
    n.parent = from;
    n.action = *a;
    n.depth = depth;
    r->nodes[r->count] = n;
    return r->count++;
}

static int check_input(const NsRrtParams *prm, const NsPlanObstacle *obs, int nobs,
                       const NsPlanPose *start, const double target[3], char *err, int err_sz)
{
    if (!(prm->kappa > 0.0) || !isfinite(prm->kappa) || !(prm->clearance >= 0.0) ||
        !isfinite(prm->clearance) || !(prm->tolerance > 0.0) || !(prm->step > 0.0) ||
        !isfinite(prm->step) || !(prm->check_step > 0.0) || !isfinite(prm->max_length) ||
        !(prm->goal_bias >= 0.0 && prm->goal_bias <= 1.0) || prm->max_nodes < 2 ||
        prm->max_nodes > 1000000 || prm->max_iterations < 1 || prm->step / prm->check_step > 1e5) {
        ns_set_err(err, err_sz,
                   "rrt: kappa %g must be > 0, clearance %g >= 0, tolerance %g, step %g and "
                   "check_step %g > 0 (step / check_step <= 1e5), goal_bias %g in [0, 1], "
                   "max_nodes %d in 2..1000000, max_iterations %d >= 1",
                   prm->kappa, prm->clearance, prm->tolerance, prm->step, prm->check_step,
                   prm->goal_bias, prm->max_nodes, prm->max_iterations);
        return -1;
    }
    for (int i = 0; i < 3; i++)
        if (!(prm->lo[i] < prm->hi[i]) || !isfinite(prm->lo[i]) || !isfinite(prm->hi[i])) {
            ns_set_err(err, err_sz, "rrt: the workspace's low corner must be below its high one");
            return -1;
        }
    if ((nobs > 0 && !obs) || nobs < 0) {
        ns_set_err(err, err_sz, "rrt: %d obstacles and no array", nobs);
        return -1;
    }
    for (int i = 0; i < nobs; i++)
        if (!ns_plan_obstacle_valid(&obs[i], err, err_sz))
            return -1;
    if (!start || !target || !pm_finite(target) || !pm_finite(start->p) || !pm_finite(start->t) ||
        !pm_finite(start->m2)) {
        ns_set_err(err, err_sz, "rrt: a missing or non-finite start or target");
        return -1;
    }
    return 0;
}

/* A plain reason for an impossible problem, before any search (1), or 0. */
static int check_ends(const NsRrtParams *prm, const NsPlanObstacle *obs, int nobs,
                      const NsPlanPose *start, const double target[3], char *err, int err_sz)
{
    int w;
    double ds = ns_plan_obstacles_distance(obs, nobs, start->p, &w);
    if (ds < prm->clearance) {
        ns_set_err(err, err_sz, "rrt: the start is %.3g mm from %s, closer than the clearance",
                   1e3 * ds, obs[w].name ? obs[w].name : "an obstacle");
        return 1;
    }
    double dt = ns_plan_obstacles_distance(obs, nobs, target, &w);
    if (dt < 0.0) {
        ns_set_err(err, err_sz, "rrt: the target is inside %s (%.3g mm deep)",
                   obs[w].name ? obs[w].name : "an obstacle", -1e3 * dt);
        return 1;
    }
    if (dt < prm->clearance) {
        ns_set_err(err, err_sz,
                   "rrt: the target is %.3g mm from %s, closer than the clearance %.3g mm",
                   1e3 * dt, obs[w].name ? obs[w].name : "an obstacle", 1e3 * prm->clearance);
        return 1;
    }
    if (!inside(prm, start->p) || !inside(prm, target)) {
        ns_set_err(err, err_sz, "rrt: the start or the target is outside the workspace");
        return 1;
    }
    return 0;
}

/* The path from the root to node `leaf`, then the action `last` (may be NULL). */
static int build_path(const Rrt *r, int leaf, const NsPlanAction *last, const double target[3],
                      NsPlanPath *path)
{
    int len = 0;
    for (int i = leaf; i > 0; i = r->nodes[i].parent)
        len++;
    int *chain = malloc(sizeof *chain * (size_t)(len + 1));
    if (!chain || !ns_plan_path_init(path, &r->nodes[0].pose, r->prm->kappa)) {
        free(chain);
        return -1;
    }
    int k = len;
    for (int i = leaf; i > 0; i = r->nodes[i].parent)
        chain[--k] = i;
    bool ok = true;
    for (int i = 0; i < len && ok; i++)
        ok = ns_plan_path_push(path, &r->nodes[chain[i]].action);
    if (ok && last)
        ok = ns_plan_path_push(path, last);
    free(chain);
    if (!ok) {
        ns_plan_path_free(path);
        return -1;
    }
    path->error = pm_dist(path->poses[path->action_count].p, target);
    path->reached = path->error <= r->prm->tolerance;
    path->clearance = ns_plan_path_clearance(path, r->obs, r->nobs, r->prm->check_step);
    return 0;
}

/* Tries to finish from node i: within tolerance already, or a clear arc to the target. 1 when
 * done (path built), 0 when not, -1 out of memory. */
static int try_goal(Rrt *r, int i, const double target[3], NsPlanPath *path)
{
    const Node *n = &r->nodes[i];
    if (pm_dist(n->pose.p, target) <= r->prm->tolerance)
        return build_path(r, i, NULL, target, path) == 0 ? 1 : -1;
    NsPlanAction a;
    if (!arc_to(&n->pose, target, r->prm->kappa, &a))
        return 0;
    if ((r->prm->max_length > 0.0 && n->depth + a.length > r->prm->max_length) ||
        !clear(r, &n->pose, &a))
        return 0;
    return build_path(r, i, &a, target, path) == 0 ? 1 : -1;
}

int ns_rrt_plan(const NsRrtParams *prm, const NsPlanObstacle *obs, int obstacle_count,
                const NsPlanPose *start, const double target[3], NsPlanPath *path,
                NsRrtStats *stats, char *err, int err_sz)
{
    if (!prm || !path) {
        ns_set_err(err, err_sz, "rrt: a NULL argument");
        return -1;
    }
    memset(path, 0, sizeof *path);
    if (check_input(prm, obs, obstacle_count, start, target, err, err_sz) != 0)
        return -1;
    int rc = check_ends(prm, obs, obstacle_count, start, target, err, err_sz);
    if (rc != 0)
        return rc;
    Rrt r = {prm, obs, obstacle_count, malloc(sizeof(Node) * (size_t)prm->max_nodes), 1, {0}};
    if (!r.nodes) {
        ns_set_err(err, err_sz, "rrt: out of memory for %d nodes", prm->max_nodes);
        return -1;
    }
    r.nodes[0] = (Node){*start, -1, {0.0, 0.0, 0.0, 0.0}, 0.0};
    NsPlanRng rng = ns_plan_rng(prm->seed);
    rc = try_goal(&r, 0, target, path);
    for (int it = 0; rc == 0 && it < prm->max_iterations && r.count < prm->max_nodes; it++) {
        r.st.iterations++;
        double q[3];
        if (ns_plan_rng_uniform(&rng) < prm->goal_bias)
            memcpy(q, target, sizeof q);
        else
            for (int k = 0; k < 3; k++)
                q[k] = ns_plan_rng_range(&rng, prm->lo[k], prm->hi[k]);
        int from = nearest(&r, q);
        NsPlanAction a;
        if (from < 0 || !arc_to(&r.nodes[from].pose, q, prm->kappa, &a))
            continue;
        a.length = fmin(a.length, prm->step);
        int added = add(&r, from, &a);
        if (added >= 0)
            rc = try_goal(&r, added, target, path);
    }
    r.st.nodes = r.count;
    if (stats)
        *stats = r.st;
    free(r.nodes);
    if (rc < 0) {
        ns_set_err(err, err_sz, "rrt: out of memory building the path");
        return -1;
    }
    if (rc == 0) {
        ns_set_err(err, err_sz,
                   "rrt: no path with %.3g mm clearance found in %d samples (%d nodes, %d arcs "
                   "refused)",
                   1e3 * prm->clearance, r.st.iterations, r.st.nodes, r.st.rejected);
        return 1;
    }
    return 0;
}

double ns_plan_path_clearance(const NsPlanPath *path, const NsPlanObstacle *obs, int count,
                              double step)
{
    double *xyz;
    int n = ns_plan_path_points(path, step, &xyz);
    if (n < 0)
        return NAN;
    double best = INFINITY;
    for (int i = 0; i < n; i++)
        best = fmin(best, ns_plan_obstacles_distance(obs, count, xyz + 3 * i, NULL));
    free(xyz);
    return best;
}
