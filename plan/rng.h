/* The planners' own pseudo-random numbers (SplitMix64, Steele, Lea, Flood 2014): a state the
 * caller owns, the same sequence for the same seed on every platform; never rand(). */
#ifndef NS_PLAN_RNG_H
#define NS_PLAN_RNG_H

#include <stdint.h>

typedef struct NsPlanRng {
    uint64_t state;
} NsPlanRng;

static inline NsPlanRng ns_plan_rng(uint64_t seed)
{
    NsPlanRng r = {seed};
    return r;
}

static inline uint64_t ns_plan_rng_next(NsPlanRng *r)
{
    uint64_t z = (r->state += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

/* uniform in [0, 1): the top 53 bits */
static inline double ns_plan_rng_uniform(NsPlanRng *r)
{
    return (double)(ns_plan_rng_next(r) >> 11) * 0x1.0p-53;
}

static inline double ns_plan_rng_range(NsPlanRng *r, double lo, double hi)
{
    return lo + (hi - lo) * ns_plan_rng_uniform(r);
}

#endif
