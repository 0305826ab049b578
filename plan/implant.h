/* Seed coverage for a brachytherapy implant (the paper's §5 "seed coverage with as few insertions
 * as possible"; docs/planning.md, "Implant planning"): which template holes to use, and how many
 * seeds each needle carries, so that the prescription dose covers a region with the fewest
 * insertions. Straight needles through the holes of a template, seeds a fixed spacing apart
 * along each track and centred in the region's span of it, dose by TG-43 (sim/dose.h) in the
 * undeformed anatomy. The choice is greedy set cover: add the needle that brings the most of the
 * region's volume to the prescription (among those that keep V150 within its bound, when any
 * does), until the coverage asked for is reached, then drop any needle the coverage does not
 * need. Deterministic: the same inputs give the same plan. */
#ifndef NS_PLAN_IMPLANT_H
#define NS_PLAN_IMPLANT_H

#include "dose.h"
#include "shape.h"

/* Bounds on the inputs (checked before the allocations they bound). */
#define NS_IMPLANT_MAX_HOLES  1024
#define NS_IMPLANT_MAX_AVOID  32
#define NS_IMPLANT_MAX_VOXELS 400000L
#define NS_IMPLANT_MAX_WORK   2e8   /* seed-voxel dose evaluations (a few seconds) */
#define NS_IMPLANT_MAX_BYTES  256e6 /* the candidates' dose vectors */
#define NS_IMPLANT_MAX_CHOICE 2e9   /* the greedy choice's voxel visits (a few seconds) */
#define NS_IMPLANT_MAX_REACH  1.0 /* a hole's distance from, and a side of, the region's box [m] */

typedef struct NsImplantParams {
    /* The anatomy: `regions` in the tissue's order, later ones overriding earlier ones where
     * they overlap (as the mesher labels them); `target` the index of the region to cover;
     * `avoid` the indices of the regions to keep `clearance` from. */
    const NsShape *const *regions;
    int region_count;
    int target;
    const int *avoid;
    int avoid_count;
    double clearance; /* [m], >= 0: a track or seed nearer an avoided region is not used */
    /* The template: hole entry points (n x 3) and the needles' common direction. */
    const double *holes;
    int hole_count;
    double direction[3];
    double spacing;       /* seed centres along a needle [m] */
    int seeds_per_needle; /* a needle's load at most (a longer span carries this many, centred) */
    double tip_offset;    /* the needle's tip beyond its deepest seed's centre [m] */
    double margin;        /* the end seeds at least this far inside the region's span [m] */
    int seeds_max;        /* the implant's seed budget */
    int needles_max;
    double prescription; /* [Gy], total dose to full decay */
    double coverage;     /* the fraction of the region to bring to the prescription (V100) */
    double v150_max;     /* a needle that keeps V150 [%] at most this is preferred (60: ABS) */
    double grid;         /* the planning grid's spacing [m] */
    const NsTg43Source *source;
    double sk; /* every seed's air-kerma strength [Gy m^2 s^-1] */
} NsImplantParams;

typedef struct NsImplantPlan {
    int needle_count;
    int *hole;         /* the chosen holes, in the template's order (needle_count) */
    int *seeds;        /* seeds each carries */
    double *deepest;   /* the deepest seed's distance from the hole along the direction [m] */
    int seed_count;    /* seeds in all */
    double *seed_pos;  /* seed centres (seed_count x 3), needle by needle, deepest first */
    int candidates;    /* holes whose track crosses the region */
    int blocked;       /* of those, the ones within the clearance of an avoided region */
    long voxels;       /* the region's voxels on the planning grid */
    double v100, v150; /* % of the region at >= 100 % and 150 % of the prescription */
    double d90;        /* the dose that 90 % of the region receives at least [Gy] */
    int reached;       /* 1 if v100 >= coverage */
} NsImplantPlan;

/* Plans the implant. Returns 0 (plan filled; free it with ns_implant_plan_free), or -1 with what
 * is wrong in err (bad parameters, a region with no voxel, no usable track, out of memory). */
int ns_plan_implant(const NsImplantParams *p, NsImplantPlan *out, char *err, int err_sz);

void ns_implant_plan_free(NsImplantPlan *plan);

#endif
