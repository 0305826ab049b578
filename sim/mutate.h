/* Mutation hooks: the physical constants a validation case must catch (issue 35's bar: "a 20%
 * change in the bevel model's coefficient, in GJ, in EI, in the tissue's E or in the friction
 * bound each fails at least one validate case").
 *
 * NS_MUTATE(name, x) marks the one place in sim/ where a constant enters the physics. In the
 * normal build it is x. In a mutation build (meson -Dmutation=true, tools/mutate.sh) it is x
 * times the factor the environment variable NS_MUTATE gives for that name
 * ("gj=1.2,youngs=0.8"; 1 for a name not listed), so one build runs every mutation.
 *
 * Names: the three bevel models' coefficients, "bevel_force" (k_b), "bevel_arc" (k_c) and
 * "bevel_disp" (the displacement's tan(psi)); "gj" and "ei" (the needle's torsional and bending
 * stiffness); "youngs" (the tissue's E); "friction" (the friction bound per unit length,
 * f_perlen). docs/validation.md lists what each mutation fails. */
#ifndef NS_MUTATE_H
#define NS_MUTATE_H

#ifdef NS_MUTATION_BUILD
/* The factor NS_MUTATE gives for name (1 when unset or not listed; exits with a message on a
 * malformed value, as a mutation run must not silently run unmutated). */
double ns_mutation_factor(const char *name);
#define NS_MUTATE(name, x) ((x)*ns_mutation_factor(name))
#else
#define NS_MUTATE(name, x) (x)
#endif

#endif
