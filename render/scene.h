/* The API-neutral scene the renderer draws (issue 8): triangles, lines and a cut plane, built
 * from the simulation's state by ns_scene_build (render/scene.c) and drawn by render/gl.c. Only
 * this file and scene.c know the sim's structures; only gl.c knows OpenGL.
 *
 * A view (paper Fig. 5) cuts the tissue with a plane: the half towards the camera is removed,
 * the cut face is capped and coloured by tissue region, the remaining outer surface is drawn
 * translucent, and the needle, targets, seeds and markers are drawn solid (and ghosted where
 * the tissue hides them). */
#ifndef NS_RENDER_SCENE_H
#define NS_RENDER_SCENE_H

#include <stdbool.h>
#include <stdint.h>

#include "mesh.h"

typedef struct NsVertex {
    float p[3], n[3]; /* world position [m], normal (unused by unlit layers) */
    uint8_t rgba[4];
} NsVertex;

/* A growable vertex list: triangles (three vertices each) or lines (two each). */
typedef struct NsVertexBuf {
    NsVertex *v;
    int n, cap;
} NsVertexBuf;

typedef struct NsCamera {
    double eye[3], target[3], up[3];
    double fov_deg; /* vertical field of view */
} NsCamera;

typedef struct NsScene {
    NsVertexBuf cap;   /* the cut face: opaque, unlit */
    NsVertexBuf edges; /* tet edges on the cut face (lines), unlit */
    NsVertexBuf solid; /* needle, sleeve, targets, seeds, markers: opaque, lit */
    NsVertexBuf glass; /* the outer tissue surface: translucent, lit, clipped by the plane */
    double plane[4];   /* the cut: points with plane . (x, 1) > 0 are removed */
    NsCamera camera;
    char label[32]; /* the view's name, drawn in its corner */
} NsScene;

/* The friction state colours (needle nodes) and the target colours, for tests and legends. */
extern const uint8_t ns_scene_needle_rgb[5][3]; /* free, sticking, sliding back, sliding, cutting */
extern const uint8_t ns_scene_hit_rgb[3], ns_scene_miss_rgb[3];
extern const uint8_t ns_scene_iso_rgb[2][3]; /* the isodose levels' colours, in order */
extern const uint8_t ns_scene_plan_rgb[3];   /* the planned path: light blue */
/* The colour of tissue region k on the cut face. */
void ns_scene_region_rgb(int region, bool obstacle, uint8_t rgb[3]);

/* side, top: the section through the insertion axis, seen level and from above; axis: a cross
 * section at the tip, seen along the needle; cutaway3d: the section through the axis seen from
 * above and ahead at an angle, the organs' surfaces (the regions' interfaces) translucent;
 * trus: a transverse ultrasound image at the tip's depth. */
typedef enum NsView {
    NS_VIEW_SIDE = 0,
    NS_VIEW_TOP = 1,
    NS_VIEW_AXIS = 2,
    NS_VIEW_CUTAWAY3D = 3,
    NS_VIEW_TRUS = 4 /* simulated ultrasound, drawn on the CPU (render/trus.h), not a scene */
} NsView;
enum { NS_VIEW_COUNT = 5 };
/* "side", "top", "axis", "cutaway3d", "trus" -> NsView, or -1. */
int ns_view_parse(const char *name);
const char *ns_view_name(NsView v);

/* What a frame shows, in world coordinates [m]: the caller reads it off the state. */
typedef struct NsSceneInput {
    const NsMesh *mesh;          /* the tissue (world positions x, regions) */
    const uint8_t *changed;      /* per tet slot: 1 if the latest remeshing made it (or NULL) */
    const bool *obstacle_region; /* per region: an obstacle (or NULL) */
    int regions;
    /* the needle */
    const double *rod_x; /* (rod_nodes x 3) */
    int rod_nodes;
    double rod_radius;
    const uint8_t *state; /* per rod node: NsFriction (NULL: no friction colours) */
    bool cutting;         /* the tip cut this step (the tip is drawn in the cutting colour) */
    bool bevel;           /* a bevel tip: m2 is the side it steers to */
    double m2[3];
    int held; /* rod nodes held by the sleeve (2: the sleeve is drawn round edge 0) */
    /* targets, seeds, markers */
    const double *target_x; /* (targets x 3) */
    const double *target_r; /* (targets) the tolerance [m] */
    const bool *target_hit;
    const double *target_x0; /* (targets x 3) where each target started, or NULL: a ghost */
    int targets;
    const double *seed_x;
    int seeds;
    const double *marker_x;
    int markers;
    /* the view */
    double axis[3], entry[3]; /* insertion axis (unit) and entry point */
    double bounds[6];         /* lo[3], hi[3]: what the camera frames (the initial tissue) */
    bool has_cut_normal;      /* the scenario's cut-plane normal instead of the default */
    double cut_normal[3];
    bool tet_edges;   /* draw the tets' edges on the cut face */
    double orbit_deg; /* the side and top views turned about the insertion axis (0: none) */
    /* isodose lines on the cut face (docs/brachytherapy.md): dose_points fills out[k] with the
     * dose [Gy] at pts[3k..3k+2] from seeds at seed_x (returns 0, else no lines); levels [Gy]
     * drawn with the colours of ns_scene_iso_rgb. NULL: none. */
    int (*dose_points)(void *ctx, const double *seed_x, int seeds, const double *pts, long n,
                       double *out);
    void *dose_ctx;
    double iso_levels[2];
    int iso_count;
    /* the path a planner predicts ahead of the tip (act.steer's latest replan, paper §5):
     * (plan_n x 3) points [m], drawn as a thin tube in ns_scene_plan_rgb. NULL: none. */
    const double *plan_x;
    int plan_n;
    /* a path planned before the run (`run --plan DIR`), drawn the same way; NULL: none */
    const double *prior_x;
    int prior_n;
    double px_size; /* the world size of one pixel at the scene's centre, for minimum sizes */
} NsSceneInput;

/* The camera of view v for in (aspect = width / height of its viewport). */
void ns_scene_camera(const NsSceneInput *in, NsView v, double aspect, NsCamera *cam);
/* Fills s (its buffers are reused) with view v of in. Returns 0, or -1 out of memory. */
int ns_scene_build(const NsSceneInput *in, NsView v, double aspect, NsScene *s);
void ns_scene_free(NsScene *s);

/* The column-major 4x4 view-projection matrix of cam, and the pixel (x right, y down, in a
 * w x h viewport) and depth of a world point; returns 0 if the point is behind the camera. */
void ns_camera_matrix(const NsCamera *cam, double aspect, double m[16]);
int ns_camera_project(const NsCamera *cam, int w, int h, const double p[3], double px[2]);

#endif
