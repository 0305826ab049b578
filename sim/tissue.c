/* The tissue: FEM forces and lazily updated Jacobians (§3.2, §3.6.3) and the Newmark step with
 * one Newton iteration on the accelerations (§3.1, Eq. 1-5). */
#include "tissue.h"

#include "err.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

NsTissueParams ns_default_tissue_params(void)
{
    NsTissueParams p;
    p.gravity[0] = p.gravity[1] = p.gravity[2] = 0.0;
    p.beta = 0.25;
    p.gamma = 0.5;
    p.lazy_threshold = 1e-3;
    p.solve_tol = 1e-8;
    p.solve_max_iter = 2000;
    return p;
}

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

void ns_tissue_free(NsTissue *t)
{
    ns_mesh_free(&t->mesh);
    free(t->materials);
    free(t->rest);
    free(t->frame);
    free(t->jframe);
    free(t->jvalid);
    free(t->mass);
    free(t->force);
    free(t->dof_fixed);
    free(t->work);
    ns_bsm_free(&t->K);
    ns_bsm_free(&t->D);
    ns_bsm_free(&t->A);
    memset(t, 0, sizeof *t);
}

int ns_tissue_init(NsTissue *t, const NsMesh *mesh, const NsTissueMaterial *materials,
                   int material_count, const NsTissueParams *params, char *err, int err_sz)
{
    memset(t, 0, sizeof *t);
    if (ns_mesh_copy(&t->mesh, mesh)) {
        ns_set_err(err, err_sz, "out of memory");
        return -1;
    }
    t->params = params ? *params : ns_default_tissue_params();
    int nn = t->mesh.node_slots, nt = t->mesh.tet_slots;
    t->material_count = material_count;
    t->materials = malloc((size_t)(material_count > 0 ? material_count : 1) * sizeof *t->materials);
    t->rest = calloc((size_t)(nt > 0 ? nt : 1), sizeof *t->rest);
    t->frame = calloc((size_t)(nt > 0 ? nt : 1), sizeof *t->frame);
    t->jframe = calloc((size_t)(nt > 0 ? nt : 1), sizeof *t->jframe);
    t->jvalid = calloc((size_t)(nt > 0 ? nt : 1), 1);
    t->mass = calloc((size_t)(nn > 0 ? nn : 1), sizeof(double));
    t->force = calloc((size_t)(3 * nn > 0 ? 3 * nn : 1), sizeof(double));
    t->dof_fixed = calloc((size_t)(3 * nn > 0 ? 3 * nn : 1), 1);
    t->work = calloc((size_t)(12 * nn > 0 ? 12 * nn : 1), sizeof(double));
    ns_bsm_init(&t->K);
    ns_bsm_init(&t->D);
    ns_bsm_init(&t->A);
    if (!t->materials || !t->rest || !t->frame || !t->jframe || !t->jvalid || !t->mass ||
        !t->force || !t->dof_fixed || !t->work || ns_bsm_resize(&t->K, nn) ||
        ns_bsm_resize(&t->D, nn) || ns_bsm_resize(&t->A, nn)) {
        ns_set_err(err, err_sz, "out of memory");
        ns_tissue_free(t);
        return -1;
    }
    for (int m = 0; m < material_count; m++) {
        const NsTissueMaterial *mt = &materials[m];
        if (!(mt->density > 0.0) || !(mt->fem.mu > 0.0) || !(mt->fem.lambda >= 0.0) ||
            !(mt->fem.damp_mu >= 0.0) || !(mt->fem.damp_lambda >= 0.0)) {
            ns_set_err(err, err_sz,
                       "material %d: density, moduli and damping must be positive "
                       "(density %g)",
                       m, mt->density);
            ns_tissue_free(t);
            return -1;
        }
        t->materials[m] = *mt;
    }
    const NsMesh *M = &t->mesh;
    for (int e = 0; e < nt; e++) {
        if (!ns_mesh_tet_alive(M, e))
            continue;
        const int *tn = M->tet_node + 4 * e;
        if (M->tet_region[e] >= material_count) {
            ns_set_err(err, err_sz, "tet %d has region %d, which has no material", e,
                       M->tet_region[e]);
            ns_tissue_free(t);
            return -1;
        }
        if (ns_fem_rest(M->u + 3 * tn[0], M->u + 3 * tn[1], M->u + 3 * tn[2], M->u + 3 * tn[3],
                        &t->rest[e])) {
            ns_set_err(err, err_sz, "tet %d is flat or inverted in material space (volume %g)", e,
                       t->rest[e].W);
            ns_tissue_free(t);
            return -1;
        }
        double m4 = t->materials[M->tet_region[e]].density * t->rest[e].W / 4.0;
        for (int k = 0; k < 4; k++)
            t->mass[tn[k]] += m4;
    }
    /* Held nodes, and slots with no node or no mass (nothing to solve for), are Dirichlet. */
    for (int i = 0; i < nn; i++)
        if ((M->flags[i] & NS_NODE_FIXED) || !(M->flags[i] & NS_NODE_ALIVE) || t->mass[i] <= 0.0)
            t->dof_fixed[3 * i] = t->dof_fixed[3 * i + 1] = t->dof_fixed[3 * i + 2] = 1;
    return 0;
}

void ns_tissue_fix_dof(NsTissue *t, int node, int axis, int fixed)
{
    if (node >= 0 && node < t->mesh.node_slots && axis >= 0 && axis < 3)
        t->dof_fixed[3 * node + axis] = (uint8_t)(fixed != 0);
}

/* Scatter a 12x12 element matrix (scaled by sign) into the block matrix at the tet's nodes. */
static void scatter(NsBlockMatrix *M, const int *tn, const double J[144], double sign)
{
    for (int a = 0; a < 4; a++)
        for (int b = 0; b < 4; b++) {
            double blk[9];
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++)
                    blk[3 * i + j] = sign * J[12 * (3 * a + i) + 3 * b + j];
            ns_bsm_add(M, tn[a], tn[b], blk);
        }
}

static void frame_product(const NsTetFrame *f, int with_s, double out[9])
{
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double v = 0.0;
            for (int k = 0; k < 3; k++)
                v += f->U[3 * i + k] * (with_s ? f->s[k] : 1.0) * f->V[3 * j + k];
            out[3 * i + j] = v;
        }
}

/* How much the tet's Jacobian may have changed since it was built (§3.6.3): the largest change
 * of an entry of R = U V^T (all the corotational Jacobian depends on) or, for neo-Hookean, of
 * F = U S V^T. Unlike U and V alone, both are well defined when singular values repeat. */
static double jacobian_change(const NsTetFrame *now, const NsTetFrame *then, int neohookean)
{
    double a[9], b[9], e = 0.0;
    frame_product(now, neohookean, a);
    frame_product(then, neohookean, b);
    for (int i = 0; i < 9; i++) {
        double d = fabs(a[i] - b[i]);
        e = d > e ? d : e;
    }
    return e;
}

/* The neo-Hookean tangent is made definite (Teran 2005) only for clearly compressed or
 * inverted tets: near rest its rotational eigenvalue lambda log J crosses zero, and clamping it
 * there would make the one-Newton-step linearization inexact for no gain in robustness. */
static int needs_projection(const NsTetFrame *f)
{
    return f->s[2] < NS_TISSUE_PROJECT_BELOW;
}

void ns_tissue_forces(NsTissue *t, int force_all, NsTissueStats *stats)
{
    double t0 = now_ms();
    NsMesh *M = &t->mesh;
    int nn = M->node_slots;
    memset(t->force, 0, (size_t)3 * nn * sizeof(double));
    int updated = 0, alive = 0, inverted = 0, nan = 0;
    if (force_all) {
        ns_bsm_zero(&t->K);
        ns_bsm_zero(&t->D);
        memset(t->jvalid, 0, (size_t)M->tet_slots);
    }
    double tj = 0.0;
    for (int e = 0; e < M->tet_slots; e++) {
        if (!ns_mesh_tet_alive(M, e))
            continue;
        alive++;
        const int *tn = M->tet_node + 4 * e;
        const double *x[4], *v[4];
        for (int k = 0; k < 4; k++) {
            x[k] = M->x + 3 * tn[k];
            v[k] = M->v + 3 * tn[k];
        }
        const NsTissueMaterial *mat = &t->materials[M->tet_region[e]];
        double f[12];
        ns_fem_tet_forces(&t->rest[e], &mat->fem, x, v, f, &t->frame[e]);
        for (int k = 0; k < 12; k++) {
            if (!isfinite(f[k])) {
                nan++;
                f[k] = 0.0;
            }
            t->force[3 * tn[k / 3] + k % 3] += f[k];
        }
        inverted += t->frame[e].s[2] <= 0.0;
        int neo = mat->fem.model == NS_MODEL_NEOHOOKEAN;
        if (!t->jvalid[e] ||
            jacobian_change(&t->frame[e], &t->jframe[e], neo) > t->params.lazy_threshold) {
            double tj0 = now_ms();
            double K[144], D[144];
            if (t->jvalid[e]) { /* take the old contribution out */
                ns_fem_tet_jacobians(&t->rest[e], &mat->fem, &t->jframe[e],
                                     needs_projection(&t->jframe[e]), K, D);
                scatter(&t->K, tn, K, -1.0);
                scatter(&t->D, tn, D, -1.0);
            }
            ns_fem_tet_jacobians(&t->rest[e], &mat->fem, &t->frame[e],
                                 needs_projection(&t->frame[e]), K, D);
            scatter(&t->K, tn, K, 1.0);
            scatter(&t->D, tn, D, 1.0);
            t->jframe[e] = t->frame[e];
            t->jvalid[e] = 1;
            updated++;
            tj += now_ms() - tj0;
        }
    }
    for (int i = 0; i < nn; i++)
        for (int c = 0; c < 3; c++)
            t->force[3 * i + c] += t->mass[i] * t->params.gravity[c];
    if (stats) {
        stats->jacobian_ms += tj;
        stats->force_ms += now_ms() - t0 - tj;
        stats->jacobian_fraction = alive ? (double)updated / alive : 0.0;
        stats->inverted = inverted;
        stats->nan_count += nan;
    }
}

/* A = M - c1 K - c2 D on K's pattern (D shares it: both are scattered at the same pairs). */
static void build_system(NsTissue *t, double c1, double c2)
{
    for (int i = 0; i < t->K.n; i++) {
        const NsBlockRow *kr = &t->K.rows[i];
        for (int p = 0; p < kr->count; p++) {
            int j = kr->col[p];
            const double *kb = kr->val + 9 * p;
            const double *db = ns_bsm_find(&t->D, i, j);
            double *ab = ns_bsm_get(&t->A, i, j);
            for (int q = 0; q < 9; q++)
                ab[q] = -c1 * kb[q] - c2 * (db ? db[q] : 0.0);
        }
        double *d = ns_bsm_get(&t->A, i, i);
        for (int c = 0; c < 3; c++)
            d[4 * c] += t->mass[i] > 0.0 ? t->mass[i] : 1.0; /* unused slots: identity */
    }
}

int ns_tissue_step(NsTissue *t, NsSolver *solver, double dt, const double *ext,
                   NsTissueStats *stats)
{
    NsTissueStats st;
    memset(&st, 0, sizeof st);
    double t0 = now_ms();
    NsMesh *M = &t->mesh;
    int n3 = 3 * M->node_slots;
    double beta = t->params.beta, gamma = t->params.gamma;
    ns_tissue_forces(t, 0, &st);
    if (t->steps == 0) {
        /* Newmark needs a consistent starting acceleration a0 = M^-1 F(x0, v0) (lumped M);
         * starting from a0 = 0 in a loaded state puts a one-off error into the energy. */
        for (int i = 0; i < n3; i++)
            M->a[i] = t->dof_fixed[i] ? 0.0 : (t->force[i] + (ext ? ext[i] : 0.0)) / t->mass[i / 3];
    }
    double ts = now_ms();
    build_system(t, beta * dt * dt, gamma * dt);
    double *rhs = t->work, *y = rhs + n3, *z = y + n3, *anew = z + n3;
    for (int i = 0; i < n3; i++) {
        y[i] = dt * M->v[i] + dt * dt * (0.5 - beta) * M->a[i];
        z[i] = dt * (1.0 - gamma) * M->a[i];
    }
    ns_bsm_mul(&t->K, y, rhs);
    ns_bsm_mul(&t->D, z, y);
    for (int i = 0; i < n3; i++) {
        rhs[i] += y[i] + t->force[i] + (ext ? ext[i] : 0.0);
        anew[i] = t->dof_fixed[i] ? 0.0 : M->a[i]; /* warm start; fixed DOFs do not accelerate */
    }
    NsSolveStats ss;
    int rc = ns_solver_solve(solver, &t->A, t->dof_fixed, rhs, anew, t->params.solve_tol,
                             t->params.solve_max_iter, &ss);
    st.solve_ms = now_ms() - ts;
    st.cg_iterations = ss.iterations;
    st.factorized = ss.factorized;
    st.unconverged = rc == 0 && !ss.converged;
    int finite = rc == 0;
    for (int i = 0; i < n3 && finite; i++)
        finite = isfinite(anew[i]);
    if (!finite) {
        st.nan_count += rc == 0;
        st.total_ms = now_ms() - t0;
        if (stats)
            *stats = st;
        return -1;
    }
    for (int i = 0; i < n3; i++) {
        M->x[i] += dt * M->v[i] + dt * dt * ((0.5 - beta) * M->a[i] + beta * anew[i]);
        M->v[i] += dt * ((1.0 - gamma) * M->a[i] + gamma * anew[i]);
        M->a[i] = anew[i];
    }
    t->steps++;
    st.total_ms = now_ms() - t0;
    if (stats)
        *stats = st;
    return 0;
}

int ns_tissue_static_solve(NsTissue *t, NsSolver *solver, const double *ext, double tol,
                           int max_newton, NsTissueStats *stats)
{
    NsTissueStats st;
    memset(&st, 0, sizeof st);
    NsMesh *M = &t->mesh;
    int n3 = 3 * M->node_slots;
    double *rhs = t->work, *dx = rhs + n3;
    int it;
    for (it = 0; it <= max_newton; it++) {
        ns_tissue_forces(t, 1, &st);
        /* Residual on free DOFs; the reference is the largest applied or reaction force. */
        double res = 0.0, ref = 1e-300;
        for (int i = 0; i < n3; i++) {
            double f = t->force[i] + (ext ? ext[i] : 0.0);
            if (t->dof_fixed[i])
                ref = fabs(f) > ref ? fabs(f) : ref;
            else
                res = fabs(f) > res ? fabs(f) : res;
            if (ext)
                ref = fabs(ext[i]) > ref ? fabs(ext[i]) : ref;
            rhs[i] = f;
            dx[i] = 0.0;
        }
        if (res <= tol * ref)
            break;
        if (it == max_newton) {
            st.unconverged++;
            break;
        }
        build_system(t, 1.0, 0.0);
        /* A = M - K: remove the mass again, the static tangent is -K. */
        for (int i = 0; i < t->A.n; i++) {
            double *d = ns_bsm_get(&t->A, i, i);
            for (int c = 0; c < 3; c++)
                d[4 * c] -= t->mass[i] > 0.0 ? t->mass[i] : 1.0;
        }
        NsSolveStats ss;
        if (ns_solver_solve(solver, &t->A, t->dof_fixed, rhs, dx, 1e-12, 20000, &ss)) {
            if (stats)
                *stats = st;
            return -1;
        }
        st.cg_iterations += ss.iterations;
        for (int i = 0; i < n3; i++)
            M->x[i] += dx[i];
    }
    if (stats)
        *stats = st;
    return it;
}

double ns_tissue_energy(const NsTissue *t)
{
    const NsMesh *M = &t->mesh;
    double e = 0.0;
    for (int i = 0; i < M->node_slots; i++) {
        if (!(M->flags[i] & NS_NODE_ALIVE))
            continue;
        const double *v = M->v + 3 * i, *x = M->x + 3 * i;
        e += 0.5 * t->mass[i] * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        e -= t->mass[i] * (t->params.gravity[0] * x[0] + t->params.gravity[1] * x[1] +
                           t->params.gravity[2] * x[2]);
    }
    for (int k = 0; k < M->tet_slots; k++) {
        if (!ns_mesh_tet_alive(M, k))
            continue;
        const int *tn = M->tet_node + 4 * k;
        const double *x[4] = {M->x + 3 * tn[0], M->x + 3 * tn[1], M->x + 3 * tn[2],
                              M->x + 3 * tn[3]};
        e += ns_fem_tet_energy(&t->rest[k], &t->materials[M->tet_region[k]].fem, x);
    }
    return e;
}
