/* Planned insertions: see path.h. */
#include "path.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

bool ns_plan_path_init(NsPlanPath *path, const NsPlanPose *start, double kappa)
{
    memset(path, 0, sizeof *path);
    if (!start || !(kappa >= 0.0) || !isfinite(kappa))
        return false;
    path->cap = 16;
    path->poses = malloc(sizeof *path->poses * (size_t)(path->cap + 1));
    path->actions = malloc(sizeof *path->actions * (size_t)path->cap);
    if (!path->poses || !path->actions) {
        ns_plan_path_free(path);
        return false;
    }
    path->poses[0] = *start;
    path->kappa = kappa;
    path->error = INFINITY;
    path->clearance = INFINITY;
    return true;
}

bool ns_plan_action_apply(const NsPlanPose *from, const NsPlanAction *a, double kappa,
                          NsPlanPose *to)
{
    if (!isfinite(a->twist) || !(a->duty >= 0.0 && a->duty <= 1.0))
        return false;
    NsPlanPose p = *from;
    ns_plan_twist(&p, a->twist);
    return ns_plan_advance(&p, ns_plan_kappa_eff(kappa, a->duty), a->rate, a->length, to);
}

bool ns_plan_path_push(NsPlanPath *path, const NsPlanAction *a)
{
    if (!path->poses)
        return false;
    NsPlanPose next;
    if (!ns_plan_action_apply(&path->poses[path->action_count], a, path->kappa, &next))
        return false;
    if (path->action_count == path->cap) {
        if (path->cap > (1 << 24))
            return false;
        int cap = path->cap * 2;
        NsPlanPose *p = realloc(path->poses, sizeof *p * (size_t)(cap + 1));
        if (!p)
            return false;
        path->poses = p;
        NsPlanAction *q = realloc(path->actions, sizeof *q * (size_t)cap);
        if (!q)
            return false;
        path->actions = q;
        path->cap = cap;
    }
    path->actions[path->action_count++] = *a;
    path->poses[path->action_count] = next;
    path->length += a->length;
    return true;
}

void ns_plan_path_free(NsPlanPath *path)
{
    free(path->poses);
    free(path->actions);
    memset(path, 0, sizeof *path);
}

int ns_plan_path_points(const NsPlanPath *path, double step, double **xyz)
{
    *xyz = NULL;
    if (!(step > 0.0) || !path->poses)
        return -1;
    size_t n = 1;
    for (int i = 0; i < path->action_count; i++) {
        double k = ceil(path->actions[i].length / step);
        if (!(k < 1e7))
            return -1;
        n += k > 1.0 ? (size_t)k : 1u;
    }
    double *out = malloc(sizeof *out * 3 * n);
    if (!out)
        return -1;
    memcpy(out, path->poses[0].p, sizeof(double) * 3);
    size_t c = 1;
    for (int i = 0; i < path->action_count; i++) {
        const NsPlanAction *a = &path->actions[i];
        NsPlanPose p = path->poses[i];
        ns_plan_twist(&p, a->twist);
        double kk = ns_plan_kappa_eff(path->kappa, a->duty), k = ceil(a->length / step);
        int m = k > 1.0 ? (int)k : 1;
        for (int j = 1; j <= m; j++) {
            NsPlanPose q;
            ns_plan_advance(&p, kk, a->rate, a->length * j / m, &q);
            memcpy(out + 3 * c++, q.p, sizeof(double) * 3);
        }
    }
    *xyz = out;
    return (int)c;
}
