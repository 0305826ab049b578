/* The gel scene of the remeshing and steering validation cases (engine/validate_insert.h): a gel
 * block (corotational, E 30 kPa, nu 0.45) on a structured grid, its four side faces clamped, the
 * needle entering the x = 0 face along +x off the grid lines. The needle punctures that face
 * (ns_remesh_skin_entry: an entry node on the surface, the tip node a tenth of a grid cell
 * inside); from there the tip remeshes its way in, driven by the sleeve and, at a given depth,
 * turned half a revolution at the base. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mesh_grid.h"
#include "quality_watch.h"
#include "validate_insert.h"

int vr_fail(NsValidateResult *r, const char *why)
{
    ns_validate_detail(r, "%s", why);
    r->pass = false;
    return -1;
}

/* Material length of the laid track nodes[0 .. np) [m]. */
static double track_length(const NsMesh *M, const int *nodes, int np)
{
    double s = 0.0;
    for (int i = 1; i < np; i++) {
        const double *p0 = M->u + 3 * nodes[i - 1], *p1 = M->u + 3 * nodes[i];
        s += sqrt((p1[0] - p0[0]) * (p1[0] - p0[0]) + (p1[1] - p0[1]) * (p1[1] - p0[1]) +
                  (p1[2] - p0[2]) * (p1[2] - p0[2]));
    }
    return s;
}

int vr_couple(NsTissue *tissue, NsRod *rod, const int *nodes, int np, const NsCouplingParams *cp,
              NsRemeshStack *entry, NsCoupled *c, char *err, int err_sz)
{
    const NsMesh *M = &tissue->mesh;
    NsNeedlePath path;
    if (ns_needle_path_init(&path, M, nodes, np, track_length(M, nodes, np), err, err_sz) ||
        ns_coupled_init(c, tissue, rod, &path, cp, err, err_sz)) {
        ns_remesh_stack_free(entry);
        ns_rod_free(rod);
        return -1;
    }
    ns_remesh_stack_free(&c->remesh);
    c->remesh = *entry;
    return 0;
}

/* The gel block of in, its side faces clamped, punctured at the entry (its splits onto *entry):
 * nodes[0] the entry node, nodes[1] the tip. Returns 0, or -1 with a message (nothing left to
 * free). */
static int gel_tissue(const Insertion *in, NsTissue *tissue, NsRemeshStack *entry, int nodes[2],
                      char *err, int err_sz)
{
    NsMesh mesh;
    int nx = (int)lround(in->len / in->h), nyz = (int)lround(in->width / in->h);
    double lo[3] = {0.0, -0.5 * in->width, -0.5 * in->width},
           hi[3] = {in->len, 0.5 * in->width, 0.5 * in->width};
    if (ns_mesh_grid_box(&mesh, lo, hi, nx, nyz, nyz, 0, err, err_sz))
        return -1;
    double a[3] = {0.0, in->offset[0], in->offset[1]}, dir[3] = {1.0, 0.0, 0.0};
    NsTissueMaterial mat = {ns_fem_material(NS_MODEL_COROTATIONAL, 30e3, 0.45, 3.0, 3.0), 1000.0};
    NsTissueParams tp = ns_default_tissue_params();
    tp.gamma = 0.55;
    tp.beta = 0.25 * 1.05 * 1.05;
    int rc = ns_tissue_init(tissue, &mesh, &mat, 1, &tp, err, err_sz);
    ns_mesh_free(&mesh);
    if (rc)
        return -1;
    const NsMesh *M = &tissue->mesh;
    /* Skin entry, its splits the first entries of the needle's undo stack. */
    ns_remesh_stack_init(entry);
    if (ns_remesh_skin_entry(&tissue->mesh, entry, a, dir, 0.1 * in->h, nodes, err, err_sz) ||
        ns_tissue_sync_topology(tissue, err, err_sz)) {
        ns_remesh_stack_free(entry);
        ns_tissue_free(tissue);
        return -1;
    }
    for (int i = 0; i < M->node_slots; i++) {
        const double *u = M->u + 3 * i;
        if (fabs(fabs(u[1]) - 0.5 * in->width) < 1e-9 || fabs(fabs(u[2]) - 0.5 * in->width) < 1e-9)
            for (int c = 0; c < 3; c++)
                ns_tissue_fix_dof(tissue, i, c, 1);
    }
    return 0;
}

/* The needle of in at the skin entry nodes[0 .. np) (gel_tissue) coupled to the tissue, remeshing
 * on: 4 edges of 5 mm outside (held by the sleeve), the entry node, the tip. The entry's stack
 * becomes the needle's. Returns 0, or -1 with a message (the stack and the rod freed, the tissue
 * left to the caller). */
static int gel_needle(const Insertion *in, NsTissue *tissue, const int *nodes, int np,
                      NsRemeshStack *entry, NsRod *rod, NsCoupled *c, char *err, int err_sz)
{
    const NsMesh *M = &tissue->mesh;
    int n = 4 + np;
    double x[3 * 24];
    const double *e0 = M->x + 3 * nodes[0];
    for (int i = 0; i < 4; i++) {
        x[3 * i] = e0[0] - 0.005 * (4 - i);
        x[3 * i + 1] = e0[1];
        x[3 * i + 2] = e0[2];
    }
    for (int i = 0; i < np; i++)
        memcpy(x + 3 * (4 + i), M->x + 3 * nodes[i], 3 * sizeof *x);
    NsRodParams rp = ns_default_rod_params();
    rp.gamma = tissue->params.gamma;
    rp.beta = tissue->params.beta;
    rp.tip = in->tip;
    rp.bevel_angle = in->bevel_deg * M_PI / 180.0;
    if (in->flexible) {
        rp.material.youngs = 50e9;
        rp.material.outer_diameter = 0.83e-3;
        rp.material.inner_diameter = 0.0;
        rp.material.density = 6450.0;
    }
    double d1[3] = {0.0, 1.0, 0.0};
    if (ns_rod_init(rod, x, n, d1, 2, &rp, err, err_sz)) {
        ns_remesh_stack_free(entry);
        return -1;
    }
    NsCouplingParams cp = ns_default_coupling_params();
    cp.f_perlen = 10.0;
    cp.cut_force[0] = 0.05;
    cp.remesh = 1;
    cp.bevel_model = in->bevel_model;
    /* The bevel force's pair of balls (docs/needle.md, "The bevel force's reaction") at 5 mm,
     * which this 4 mm grid resolves: the default 15 mm, sized for the phantom's 13 mm mesh, would
     * reach from a path 4 mm off a clamped face (bevel-arc's) well into it. */
    cp.tip_load_radius = 5e-3;
    return vr_couple(tissue, rod, nodes, np, &cp, entry, c, err, err_sz);
}

int vr_insert(const Insertion *in, Run *run, NsValidateResult *r)
{
    memset(run, 0, sizeof *run);
    run->min_dihedral = 180.0;
    run->twist_step = -1;
    char err[256];
    int nodes[2], np = 2;
    NsTissue tissue;
    NsRemeshStack entry;
    if (gel_tissue(in, &tissue, &entry, nodes, err, sizeof err))
        return vr_fail(r, err);
    const NsMesh *M = &tissue.mesh;
    NsRod rod;
    NsCoupled c;
    if (gel_needle(in, &tissue, nodes, np, &entry, &rod, &c, err, sizeof err)) {
        ns_tissue_free(&tissue);
        return vr_fail(r, err);
    }
    int rc = 0;
    NsDihedralWatch dw; /* from the mesh after the skin entry (gel_tissue) */
    if (ns_dihedral_watch_init(&dw, M))
        rc = vr_fail(r, "out of memory");
    else if (getenv("NS_VALIDATE_TRACE"))
        fprintf(stderr, "after the skin entry: worst dihedral %.2f deg\n", dw.min_rest_deg);
    /* The sleeve drives the needle in by `depth`; a twist pauses the insertion while the base
     * turns half a revolution (pause steps). */
    int pause = in->twist_at > 0.0 ? (int)ceil(M_PI / (in->twist_rate * in->dt) - 1e-9) : 0;
    int steps = (int)lround(in->depth / (in->speed * in->dt)) + pause;
    run->tip = malloc((size_t)steps * 3 * sizeof *run->tip);
    if (!run->tip)
        rc = vr_fail(r, "out of memory");
    double entry_x = M->x[3 * nodes[0]], turned = 0.0, twist_u[3] = {0, 0, 0};
    for (int k = 0; k < steps && rc == 0; k++) {
        double depth = rod.x[3 * (rod.nodes - 1)] - entry_x;
        if (in->twist_at > 0.0 && depth >= in->twist_at && run->twist_step < 0)
            run->twist_step = k;
        int twisting = run->twist_step >= 0 && turned < M_PI - 1e-9;
        rod.v_insert = twisting ? 0.0 : in->speed;
        rod.twist_rate = twisting ? fmin(in->twist_rate, (M_PI - turned) / in->dt) : 0.0;
        turned += rod.twist_rate * in->dt;
        NsCouplingStats st;
        int src = ns_coupled_step(&c, in->dt, NULL, NULL, &st);
        if (src) {
            const double *tp_ = rod.x + 3 * (rod.nodes - 1);
            snprintf(err, sizeof err,
                     "coupled step %d failed (tip at %.2f, %.2f, %.2f mm; nan %d, unconverged %d, "
                     "consistent %d)",
                     k, 1e3 * tp_[0], 1e3 * tp_[1], 1e3 * tp_[2], st.nan_count, st.unconverged,
                     st.consistent);
            rc = vr_fail(r, err);
            break;
        }
        run->ops[st.remesh_kind]++;
        run->max_substeps =
            st.remesh_substeps > run->max_substeps ? st.remesh_substeps : run->max_substeps;
        run->substeps += st.remesh_substeps;
        run->min_dihedral = fmin(run->min_dihedral, st.min_dihedral_deg);
        run->max_dihedral = fmax(run->max_dihedral, st.max_dihedral_deg);
        if (ns_dihedral_watch_look(&dw, M)) {
            rc = vr_fail(r, "out of memory");
            break;
        }
        if (ns_coupled_check_structure(&c, err, sizeof err)) {
            if (run->structure_failures++ == 0)
                snprintf(run->first_failure, sizeof run->first_failure, "step %d: %.200s", k, err);
        }
        memcpy(run->tip + 3 * k, rod.x + 3 * (rod.nodes - 1), 3 * sizeof(double));
        if (k == run->twist_step) /* the material point the tip is at as the twist begins */
            memcpy(twist_u, M->u + 3 * c.path.node[c.path.count - 1], sizeof twist_u);
        const double *xt = tissue.mesh.x + 3 * c.path.node[c.path.count - 1],
                     *xr = rod.x + 3 * (rod.nodes - 1);
        run->tip_gap = fmax(run->tip_gap, sqrt((xt[0] - xr[0]) * (xt[0] - xr[0]) +
                                               (xt[1] - xr[1]) * (xt[1] - xr[1]) +
                                               (xt[2] - xr[2]) * (xt[2] - xr[2])));
        if (getenv("NS_VALIDATE_TRACE"))
            fprintf(stderr,
                    "%4d tip %.3f %.3f %.3f mm remesh %d bevel force %.3f N dihedral %.2f "
                    "(changed tets %.2f, repaired %d)\n",
                    k, 1e3 * rod.x[3 * (rod.nodes - 1)], 1e3 * rod.x[3 * (rod.nodes - 1) + 1],
                    1e3 * rod.x[3 * (rod.nodes - 1) + 2], st.remesh_kind, st.bevel_force,
                    st.min_dihedral_deg, dw.last_rest_deg, st.remesh_repaired);
        run->steps = k + 1;
    }
    if (rc == 0 && run->twist_step >= 0) {
        /* The path the needle lies on in the deformed tissue, and the twist point on it. */
        run->shape = malloc(3 * (size_t)c.path.count * sizeof *run->shape);
        double b[4];
        int t = ns_mesh_locate(M, twist_u, -1, 1e-9, b);
        if (!run->shape || t < 0) {
            rc = vr_fail(r, t < 0 ? "the twist point is not in the tissue" : "out of memory");
        } else {
            for (int i = 0; i < c.path.count; i++)
                memcpy(run->shape + 3 * i, M->x + 3 * c.path.node[i], 3 * sizeof(double));
            run->shape_count = c.path.count;
            for (int i = 0; i < 3; i++) {
                run->twist_point[i] = 0.0;
                for (int j = 0; j < 4; j++)
                    run->twist_point[i] += b[j] * M->x[3 * M->tet_node[4 * t + j] + i];
            }
        }
    }
    run->min_dihedral_any = dw.min_rest_deg;
    run->min_dihedral_any_world = dw.min_world_deg;
    ns_dihedral_watch_free(&dw);
    ns_coupled_free(&c);
    ns_rod_free(&rod);
    ns_tissue_free(&tissue);
    return rc;
}

Insertion vr_default_insertion(void)
{
    Insertion in = {0.1,           0.032, 0.004, {0.37 * 0.004, -0.23 * 0.004},
                    0.08,          0.02,  0.01,  NS_TIP_SYMMETRIC,
                    0.0,           0,     0.0,   0.0,
                    NS_BEVEL_FORCE};
    return in;
}
