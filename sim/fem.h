/* Invertible finite elements for the tissue (paper §3.2, Irving, Teran & Fedkiw 2004):
 * per-tet deformation gradient, its inversion-safe SVD F = U diag(s) V^T, first Piola-Kirchhoff
 * stress from a hyperelastic model evaluated on the diagonal, elastic and damping forces, and
 * their Jacobians with U and V held fixed.
 *
 * Units: positions [m], velocities [m/s], moduli [Pa], damping coefficients [Pa s],
 * forces [N], stiffness [N/m], damping matrices [N s/m]. */
#ifndef NS_FEM_H
#define NS_FEM_H

typedef enum NsElasticModel {
    NS_MODEL_COROTATIONAL, /* linear elasticity in the element's rotated frame */
    NS_MODEL_NEOHOOKEAN,   /* compressible neo-Hookean, extrapolated below s_min (Irving) */
} NsElasticModel;

typedef struct NsFemMaterial {
    NsElasticModel model;
    double mu;          /* Lame shear modulus [Pa] */
    double lambda;      /* Lame first parameter [Pa] */
    double damp_mu;     /* damping shear coefficient [Pa s] */
    double damp_lambda; /* damping volumetric coefficient [Pa s] */
} NsFemMaterial;

/* Lame parameters from Young's modulus [Pa] and Poisson's ratio. */
NsFemMaterial ns_fem_material(NsElasticModel model, double youngs, double poisson, double damp_mu,
                              double damp_lambda);

/* Rest data of one tet: Bm = Dm^-1 with Dm = [u1-u0, u2-u0, u3-u0] (row-major), and the rest
 * volume W [m^3]. */
typedef struct NsTetRest {
    double Bm[9];
    double W;
} NsTetRest;

/* Returns 0, or -1 if the rest tet is flat or inverted (W <= 0). */
int ns_fem_rest(const double *u0, const double *u1, const double *u2, const double *u3,
                NsTetRest *out);

/* What a force evaluation leaves for the Jacobians: the SVD of F (s[2] < 0 when inverted). */
typedef struct NsTetFrame {
    double U[9], V[9], s[3];
} NsTetFrame;

/* Below this singular value the neo-Hookean stress is extrapolated linearly (Irving 2004 §5),
 * so inverted and nearly flat elements give finite, restoring forces. */
#define NS_FEM_NEOHOOKEAN_S_MIN 0.3

/* Elastic + damping forces on the tet's four nodes, f (4 x 3), and the frame.
 * x[k], v[k]: the nodes' world positions and velocities. */
void ns_fem_tet_forces(const NsTetRest *r, const NsFemMaterial *mat, const double *const x[4],
                       const double *const v[4], double f[12], NsTetFrame *frame);

/* ns_fem_tet_forces in two parts, for callers that decompose many tets' F at once
 * (ns_svd3_n): the deformation gradient F at positions x, then the forces given frame = the
 * SVD of that F. The same bits as ns_fem_tet_forces. */
void ns_fem_tet_gradient(const NsTetRest *r, const double *const x[4], double F[9]);
void ns_fem_tet_forces_svd(const NsTetRest *r, const NsFemMaterial *mat, const double *const v[4],
                           double f[12], const NsTetFrame *frame);
/* ns_fem_tet_forces_svd for n tets (tet k: r[k], mat[k], its nodes' velocities v[k][0..3], f[k],
 * frame[k]), four at a time on vector lanes; the same bits as one at a time. */
void ns_fem_tet_forces_svd_n(int n, const NsTetRest *const r[], const NsFemMaterial *const mat[],
                             const double *const *const v[], double *const f[],
                             const NsTetFrame *const frame[]);

/* The same forces with a given frame held fixed (U, V from frame; the model's stress is
 * evaluated on U^T F V as a full matrix). Used to check the Jacobians by finite differences. */
void ns_fem_tet_forces_fixed_frame(const NsTetRest *r, const NsFemMaterial *mat,
                                   const NsTetFrame *frame, const double *const x[4],
                                   const double *const v[4], double f[12]);

/* df/dx (K) and df/dv (D) with the frame held fixed: 12 x 12 row-major, block (a, b) is
 * d f_a / d x_b. For neo-Hookean, K's diagonal-space blocks are projected to be negative
 * semi-definite (Teran et al. 2005) when project is nonzero, so -K is a stiffness the solver
 * can trust; the corotational K and the damping D are symmetric negative semi-definite as
 * they stand. */
void ns_fem_tet_jacobians(const NsTetRest *r, const NsFemMaterial *mat, const NsTetFrame *frame,
                          int project, double K[144], double D[144]);

/* The corotational model's Jacobians in closed form, one block row at a time. With R = U V^T
 * held fixed the stress is linear in F, so block (a, b) of dF/dx is
 *   -W [mu (g_a . g_b) I + mu h_b h_a^T + lambda h_a h_b^T],  h_a = R g_a,
 * (g_a the shape-function gradients) and of dF/dv the same with damp_mu and damp_lambda: what
 * ns_fem_tet_jacobians gives for this model, to round-off, from 12 numbers a tet instead of 288.
 * Adds blocks (a, b), b = 0..3, to kb[b] and db[b] (3 x 3 row-major); with R_old non-NULL, adds
 * instead their change from rotation R_old to R (only the h terms change). */
void ns_fem_corot_row(const NsTetRest *r, const NsFemMaterial *mat, const double R[9],
                      const double *R_old, int a, double *const kb[4], double *const db[4]);

/* Elastic energy of the tet [J] (for tests: forces are its negative gradient for neo-Hookean,
 * and for corotational with the frame held fixed). */
double ns_fem_tet_energy(const NsTetRest *r, const NsFemMaterial *mat, const double *const x[4]);

#endif
