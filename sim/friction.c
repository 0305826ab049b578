/* Stick-slip friction at the coupling nodes (sim/friction.h): the known force of a state
 * (Eq. 10), the checks of Eq. 9-11, and Algorithm 3's tried set with its lexicographic next. */
#include "friction.h"
#include "coupled_system.h"

#include <stdlib.h>
#include <string.h>

double coupled_known_force(const CoupledSystem *S, int k, int s)
{
    if (s == NS_FRICTION_DYN_POS)
        return -(S->f[k] + (k == S->tip ? S->f_cut : 0.0)); /* the tip cuts: Eq. 10's f_cut */
    if (s == NS_FRICTION_DYN_NEG)
        return S->f[k];
    return 0.0;
}

double coupled_rel_slide(const CoupledSystem *S, int k, const double *at, const double *ar)
{
    double ah[3];
    coupled_point(S, k, at, ah);
    const double *an = ar + 3 * S->idx[k], *t = S->R + 9 * k;
    double d = 0.0;
    for (int i = 0; i < 3; i++)
        d += t[i] * (S->yrel[3 * k + i] + S->bdt2 * (ah[i] - an[i]));
    return d;
}

/* Slack of the checks: forces within 1e-6 of the threshold, slides of 1e-10 m, count as met
 * (the solves are iterative; a node exactly at its threshold must not flip back and forth). */
#define FORCE_SLACK 1e-3
#define SLIDE_SLACK 1e-9

/* Checks node k (Eq. 9-11) in state s with forces cf and relative slide (tissue minus needle);
 * returns the state a flip would give (s itself where consistent). */
static uint8_t check_node(const CoupledSystem *S, int k, uint8_t s, const double *cf, double slide)
{
    if (s == NS_FRICTION_STATIC) {
        /* Eq. 9 / 10: the tangential force on the needle within the static threshold (the tip
         * also holds back up to f_cut before it cuts). */
        double c1 = cf[3 * k], hi = S->f[k], lo = -(S->f[k] + (k == S->tip ? S->f_cut : 0.0));
        double slack = FORCE_SLACK * (S->f[k] + S->f_cut) + 1e-12;
        if (c1 > hi + slack || c1 < lo - slack)
            return c1 < 0.0 ? NS_FRICTION_DYN_POS : NS_FRICTION_DYN_NEG;
    } else if (s != NS_FRICTION_FREE) {
        /* Eq. 11: the needle slides in its state's direction (needle minus tissue along t). */
        double sgn = s == NS_FRICTION_DYN_POS ? 1.0 : -1.0;
        if (-sgn * slide < -SLIDE_SLACK)
            return NS_FRICTION_STATIC;
    }
    return s;
}

int coupled_check_slides(const CoupledSystem *S, const uint8_t *st, const double *cf,
                         const double *slide, uint8_t *next)
{
    int bad = 0;
    for (int k = 0; k < S->q; k++) {
        next[k] = check_node(S, k, st[k], cf, slide[k]);
        bad += next[k] != st[k];
    }
    return bad;
}

int coupled_check(const CoupledSystem *S, const uint8_t *st, const double *cf, const double *at,
                  const double *ar, uint8_t *next)
{
    int bad = 0;
    for (int k = 0; k < S->q; k++) {
        double slide = st[k] == NS_FRICTION_STATIC ? 0.0 : coupled_rel_slide(S, k, at, ar);
        next[k] = check_node(S, k, st[k], cf, slide);
        bad += next[k] != st[k];
    }
    return bad;
}

void tried_init(TriedSet *T, int q, uint8_t *buf, int cap)
{
    T->count = 0;
    T->q = q;
    T->cfg = buf;
    T->cap = buf ? cap : 0;
    T->owned = 0;
}

void tried_free(TriedSet *T)
{
    if (T->owned)
        free(T->cfg);
    tried_init(T, T->q, NULL, 0);
}

int tried_add(TriedSet *T, const uint8_t *st)
{
    if (T->count == T->cap) {
        int cap = T->cap ? 2 * T->cap : 16;
        size_t q = (size_t)(T->q > 0 ? T->q : 1);
        uint8_t *p = malloc((size_t)cap * q);
        if (!p)
            return -1;
        if (T->count)
            memcpy(p, T->cfg, (size_t)T->count * q);
        if (T->owned)
            free(T->cfg);
        T->cfg = p;
        T->cap = cap;
        T->owned = 1;
    }
    memcpy(T->cfg + (size_t)T->count * (size_t)T->q, st, (size_t)T->q);
    T->count++;
    return 0;
}

static int tried_has(const TriedSet *T, const uint8_t *st)
{
    for (int i = 0; i < T->count; i++)
        if (memcmp(T->cfg + (size_t)i * (size_t)T->q, st, (size_t)T->q) == 0)
            return 1;
    return 0;
}

void tried_next(const TriedSet *T, uint8_t *st)
{
    /* Digits STATIC < DYNAMIC- < DYNAMIC+ per coupling node, node 0 (the entry) least
     * significant; bounded, since 3^q may be astronomically large. */
    for (int guard = 0; guard < 100000 && tried_has(T, st); guard++)
        for (int k = 0; k < T->q; k++) {
            if (st[k] == NS_FRICTION_STATIC) {
                st[k] = NS_FRICTION_DYN_NEG;
                break;
            }
            if (st[k] == NS_FRICTION_DYN_NEG) {
                st[k] = NS_FRICTION_DYN_POS;
                break;
            }
            st[k] = NS_FRICTION_STATIC; /* carry */
        }
}
