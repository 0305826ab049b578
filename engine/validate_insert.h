/* Inside the remeshing and steering validation cases (engine/validate_remesh.c,
 * engine/validate_steering.c): the gel scene's insertion they share (engine/validate_insert.c).
 * Not for other files. */
#ifndef NS_VALIDATE_INSERT_H
#define NS_VALIDATE_INSERT_H

#include "coupling.h"
#include "validate.h"

/* The bar on min_dihedral_deg_any_step, the whole mesh's worst dihedral angle at rest over every
 * step (sim/quality_watch.h), of every remeshing case [deg]: issue 35's; the paper reports 10.3
 * to 160 deg over its runs (§3.4.1). */
#define NS_MIN_DIHEDRAL_ANY_STEP_DEG 5.0

typedef struct Insertion {
    double len, width, h;    /* block [m], grid spacing [m] */
    double offset[2];        /* entry (y, z) off the block's centre line [m] */
    double depth, speed, dt; /* insertion depth [m], sleeve speed [m/s], step [s] */
    NsTipKind tip;
    double bevel_deg; /* psi for a bevel tip [deg] */
    int flexible;    /* 1: a solid nitinol needle of 0.83 mm (Webster et al. 2006); 0: 18 G steel */
    double twist_at; /* depth at which the base turns 180 degrees (0: never) [m] */
    double twist_rate; /* [rad/s] */
    NsBevelModel bevel_model;
} Insertion;

typedef struct Run {
    int steps;
    double *tip;                       /* (steps x 3) tip world positions */
    int ops[5];                        /* remesh operations by kind */
    double min_dihedral, max_dihedral; /* near the needle (NsCouplingStats), every step */
    /* min_dihedral_deg_any_step: the whole mesh's worst at rest over the entry and every step,
     * and deformed (sim/quality_watch.h) [deg] */
    double min_dihedral_any, min_dihedral_any_world;
    int structure_failures;
    char first_failure[300];
    double tip_gap;   /* largest distance between the needle's tip and its tissue node [m] */
    int twist_step;   /* the step at which the twist began (-1: none) */
    int max_substeps; /* most pieces a step's remeshing was cut into (§3.4.1) */
    long substeps;    /* pieces over all steps */
    /* At the end: the needle's path in the tissue (world positions of its tissue nodes, entry
     * first), and where the material point the tip was at when the twist began is now */
    double *shape;
    int shape_count;
    double twist_point[3];
} Run;

/* The symmetric 18 G needle 8 cm into the 100 x 32 x 32 mm block (4 mm grid) at 20 mm/s in
 * 10 ms steps, entering off the grid lines; bevel force steering, no twist. */
Insertion vr_default_insertion(void);

/* Builds the scene and inserts the needle; fills run (tip path, operation counts, structural
 * checks after every step; with a twist, the needle's path at the end and the twist point).
 * run->tip and run->shape are the caller's to free, whatever it returns: 0, or -1 through
 * vr_fail. */
int vr_insert(const Insertion *in, Run *run, NsValidateResult *r);

/* Couples rod to the tissue with cp along the laid track nodes[0 .. np) (its skin entry's nodes,
 * nodes[0] on the surface), the entry's stack becoming the needle's. Returns 0, or -1 with a
 * message (the stack and the rod freed). */
int vr_couple(NsTissue *tissue, NsRod *rod, const int *nodes, int np, const NsCouplingParams *cp,
              NsRemeshStack *entry, NsCoupled *c, char *err, int err_sz);

/* Adds why to r's detail, fails the case; returns -1. */
int vr_fail(NsValidateResult *r, const char *why);

#endif
