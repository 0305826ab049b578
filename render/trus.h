/* The trus view (docs/rendering.md): a simulated transrectal ultrasound image, transverse, of
 * the deformed tissue at the needle tip's depth. Drawn on the CPU from the mesh: each region's
 * echo level, speckle fixed in the tissue (a hash of the material point, so it moves with
 * the tissue), bright interfaces between regions, the needle where it crosses the image plane
 * as a bright dot with a comet tail and an acoustic shadow, seeds as bright dots; the probe's
 * fan and depth ticks. Plausible, cheap and deterministic: not a wave simulation. */
#ifndef NS_RENDER_TRUS_H
#define NS_RENDER_TRUS_H

#include "image.h"
#include "scene.h"

/* The probe: parallel to the insertion axis below the tissue (15 % up from the bottom of the
 * framed box along the world's up, centred across it), imaging the plane across the axis at
 * the needle tip's depth; the fan opens 120 degrees upwards and reaches the box's top. */
typedef struct NsTrusPose {
    double apex[3], up[3], side[3], axis[3]; /* the probe's point in the plane; unit vectors */
    double range;                            /* the fan's depth [m] */
} NsTrusPose;

void ns_trus_pose(const NsSceneInput *in, NsTrusPose *p);
/* The pixel of world point x (its part in the image plane) in a w x h panel; 0 outside it. */
int ns_trus_project(const NsTrusPose *p, int w, int h, const double x[3], double px[2]);
/* Draws the view into the w x h rectangle of im at column x0. */
void ns_trus_draw(const NsSceneInput *in, NsImage *im, int x0, int w, int h);

#endif
