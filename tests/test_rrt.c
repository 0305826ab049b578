/* plan/obstacle.c and plan/rrt.c: signed distances against hand values; an RRT over arcs
 * around an obstacle on the straight line, with the clearance respected along the whole path;
 * an impossible layout refused cleanly; the same seed giving the same path, bit for bit. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "ns_test.h"
#include "rrt.h"

static int distances(void)
{
    double c[3] = {0, 0, 0}, a[3] = {0, 0, 0}, b[3] = {0, 0, 0.02}, lo[3] = {-1, -1, -1},
           hi[3] = {1, 2, 3};
    NsPlanObstacle s = ns_plan_sphere(c, 0.01), cap = ns_plan_capsule(a, b, 0.005),
                   cyl = ns_plan_cylinder(a, b, 0.005), box = ns_plan_box(lo, hi);
    double p1[3] = {0.03, 0.04, 0}, p2[3] = {0, 0, 0.03}, p3[3] = {0.01, 0, 0.01},
           p4[3] = {0.01, 0, 0.03}, p5[3] = {0.001, 0, 0.01}, p6[3] = {0, 0, 0.0195};
    ENSURE_SMALL(ns_plan_obstacle_distance(&s, p1) - 0.04, 1e-15);
    ENSURE_SMALL(ns_plan_obstacle_distance(&cap, p2) - 0.005, 1e-15);
    ENSURE_SMALL(ns_plan_obstacle_distance(&cap, p3) - 0.005, 1e-15);
    ENSURE_SMALL(ns_plan_obstacle_distance(&cyl, p3) - 0.005, 1e-15);
    ENSURE_SMALL(ns_plan_obstacle_distance(&cyl, p2) - 0.01, 1e-15);
    /* beyond the rim: to the edge circle */
    ENSURE_SMALL(ns_plan_obstacle_distance(&cyl, p4) - sqrt(0.005 * 0.005 + 0.01 * 0.01), 1e-15);
    /* inside: to the nearer of the side (4 mm) and the cap (0.5 mm) */
    ENSURE_SMALL(ns_plan_obstacle_distance(&cyl, p5) + 0.004, 1e-15);
    ENSURE_SMALL(ns_plan_obstacle_distance(&cyl, p6) + 0.0005, 1e-15);
    double q1[3] = {2, 3, 3}, q2[3] = {0, 1.5, 0};
    ENSURE_SMALL(ns_plan_obstacle_distance(&box, q1) - sqrt(2.0), 1e-15);
    ENSURE_SMALL(ns_plan_obstacle_distance(&box, q2) + 0.5, 1e-15);
    NsPlanObstacle all[4] = {s, cap, cyl, box};
    int w;
    ENSURE_SMALL(ns_plan_obstacles_distance(all, 4, q2, &w) + 0.5, 1e-15);
    ENSURE(w == 3);
    char err[256];
    NsPlanObstacle bad = ns_plan_cylinder(a, a, 0.01);
    ENSURE(!ns_plan_obstacle_valid(&bad, err, sizeof err));
    bad = ns_plan_box(hi, lo);
    ENSURE(!ns_plan_obstacle_valid(&bad, err, sizeof err));
    bad = ns_plan_sphere(c, -1.0);
    ENSURE(!ns_plan_obstacle_valid(&bad, err, sizeof err));
    return 0;
}

/* Entry at the origin along +x, target 80 mm ahead on the axis, a sphere of 4 mm radius
 * halfway on the straight line; kappa 20 1/m (50 mm radius), clearance 1 mm. */
typedef struct Blocked {
    NsRrtParams prm;
    NsPlanObstacle obs[2];
    NsPlanPose start;
    double target[3];
} Blocked;

static Blocked blocked(void)
{
    Blocked b;
    double lo[3] = {0, -0.03, -0.03}, hi[3] = {0.1, 0.03, 0.03}, o[3] = {0, 0, 0}, x[3] = {1, 0, 0},
           y[3] = {0, 1, 0}, c[3] = {0.04, 0, 0}, ca[3] = {0.06, -0.03, 0.012},
           cb[3] = {0.06, 0.03, 0.012};
    b.prm = ns_rrt_default(20.0, lo, hi);
    b.prm.clearance = 1e-3;
    b.prm.tolerance = 1e-3;
    b.prm.seed = 7;
    b.obs[0] = ns_plan_sphere(c, 0.004);
    b.obs[0].name = "sphere";
    /* and a rod across, above the axis further in */
    b.obs[1] = ns_plan_cylinder(ca, cb, 0.003);
    b.obs[1].name = "rod";
    ns_plan_pose_make(o, x, y, &b.start);
    b.target[0] = 0.08;
    b.target[1] = 0.0;
    b.target[2] = 0.0;
    return b;
}

static int around_obstacle(void)
{
    Blocked b = blocked();
    const int runs = 15;
    double ms[15];
    int solved = 0;
    for (int i = 0; i < runs; i++) {
        b.prm.seed = 100 + (uint64_t)i;
        NsPlanPath path;
        NsRrtStats st;
        char err[256];
        struct timespec t0, t1;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        int rc = ns_rrt_plan(&b.prm, b.obs, 2, &b.start, b.target, &path, &st, err, sizeof err);
        clock_gettime(CLOCK_MONOTONIC, &t1);
        ms[i] = 1e3 * (t1.tv_sec - t0.tv_sec) + 1e-6 * (t1.tv_nsec - t0.tv_nsec);
        if (rc != 0) {
            fprintf(stderr, "seed %d: %s\n", 100 + i, err);
            continue;
        }
        solved++;
        ENSURE(path.reached && path.error <= b.prm.tolerance);
        ENSURE(path.clearance >= b.prm.clearance);
        /* checked independently, 20x finer than the planner's checks */
        double fine = ns_plan_path_clearance(&path, b.obs, 2, 12.5e-6);
        ENSURE(fine >= b.prm.clearance);
        for (int a = 0; a < path.action_count; a++)
            ENSURE(path.actions[a].duty >= 0.0 && path.actions[a].duty <= 1.0);
        if (i == 0)
            printf("  seed 100: %d actions, length %.1f mm, error %.2e mm, clearance %.3f mm "
                   "(fine check %.3f), %d nodes\n",
                   path.action_count, 1e3 * path.length, 1e3 * path.error, 1e3 * path.clearance,
                   1e3 * fine, st.nodes);
        ns_plan_path_free(&path);
    }
    /* median planning time */
    for (int i = 1; i < runs; i++)
        for (int j = i; j > 0 && ms[j] < ms[j - 1]; j--) {
            double t = ms[j];
            ms[j] = ms[j - 1];
            ms[j - 1] = t;
        }
    printf("  %d/%d seeds solved; planning ms median %.2f, max %.2f\n", solved, runs, ms[runs / 2],
           ms[runs - 1]);
    ENSURE(solved == runs);
    return 0;
}

/* A wall across the whole workspace between the entry and the target. */
static int impossible(void)
{
    Blocked b = blocked();
    double lo[3] = {0.04, -0.05, -0.05}, hi[3] = {0.045, 0.05, 0.05};
    b.obs[0] = ns_plan_box(lo, hi);
    b.obs[0].name = "wall";
    b.prm.max_iterations = 5000;
    NsPlanPath path;
    char err[256] = "";
    ENSURE(ns_rrt_plan(&b.prm, b.obs, 2, &b.start, b.target, &path, NULL, err, sizeof err) == 1);
    ENSURE(path.poses == NULL && path.action_count == 0);
    ENSURE(strstr(err, "no path") != NULL);
    printf("  wall: %s\n", err);
    /* a target inside an obstacle is refused before any search */
    b = blocked();
    b.target[0] = 0.04;
    ENSURE(ns_rrt_plan(&b.prm, b.obs, 2, &b.start, b.target, &path, NULL, err, sizeof err) == 1);
    ENSURE(strstr(err, "sphere") != NULL);
    printf("  inside: %s\n", err);
    /* bad input */
    b = blocked();
    b.prm.kappa = 0.0;
    ENSURE(ns_rrt_plan(&b.prm, b.obs, 2, &b.start, b.target, &path, NULL, err, sizeof err) == -1);
    b = blocked();
    b.obs[1].radius = NAN;
    ENSURE(ns_rrt_plan(&b.prm, b.obs, 2, &b.start, b.target, &path, NULL, err, sizeof err) == -1);
    b = blocked();
    b.prm.hi[0] = -1.0;
    ENSURE(ns_rrt_plan(&b.prm, b.obs, 2, &b.start, b.target, &path, NULL, err, sizeof err) == -1);
    return 0;
}

static int same_seed_same_path(void)
{
    Blocked b = blocked();
    NsPlanPath p1, p2, p3;
    char err[256];
    ENSURE(ns_rrt_plan(&b.prm, b.obs, 2, &b.start, b.target, &p1, NULL, err, sizeof err) == 0);
    ENSURE(ns_rrt_plan(&b.prm, b.obs, 2, &b.start, b.target, &p2, NULL, err, sizeof err) == 0);
    ENSURE(p1.action_count == p2.action_count);
    ENSURE(
        ns_same_bits((const double *)p1.actions, (const double *)p2.actions, 4 * p1.action_count));
    ENSURE(ns_same_bits((const double *)p1.poses, (const double *)p2.poses,
                        9 * (p1.action_count + 1)));
    b.prm.seed = 8;
    ENSURE(ns_rrt_plan(&b.prm, b.obs, 2, &b.start, b.target, &p3, NULL, err, sizeof err) == 0);
    ENSURE(
        p3.action_count != p1.action_count ||
        !ns_same_bits((const double *)p1.actions, (const double *)p3.actions, 4 * p1.action_count));
    ns_plan_path_free(&p1);
    ns_plan_path_free(&p2);
    ns_plan_path_free(&p3);
    return 0;
}

NS_TEST_MAIN({"distances", distances}, {"around_obstacle", around_obstacle},
             {"impossible", impossible}, {"same_seed_same_path", same_seed_same_path})
