-- Measured speed-against-accuracy fronts: written by tools/speed_accuracy.py (do not edit;
-- docs/performance.md). Per scenario, the Pareto-optimal settings, cheapest first: tip_error
-- is the largest tip distance from the converged reference run [m], cost the median step
-- time per simulated second [ms/s] on the project's 2-core machine.
return {
    brachytherapy = {
        { label = "dt=0.02 lazy=0.05 tol=1e-06", dt = 0.02, refine = 1.0, tolerance = 1e-06, lazy_threshold = 0.05,
          tip_error = 0.00043187, cost = 2545.1 },
        { label = "tol=0.0001", dt = 0.01, refine = 1.0, tolerance = 0.0001, lazy_threshold = 0.01,
          tip_error = 0.0003378, cost = 4513.76 },
        { label = "dt=0.005", dt = 0.005, refine = 1.0, tolerance = 1e-08, lazy_threshold = 0.01,
          tip_error = 3.51584e-05, cost = 10879.2 },
    },
    phantom = {
        { label = "dt=0.02 lazy=0.05 tol=0.0001", dt = 0.02, refine = 1.0, tolerance = 0.0001, lazy_threshold = 0.05,
          tip_error = 0.00353664, cost = 325.27 },
        { label = "dt=0.02 tol=1e-06", dt = 0.02, refine = 1.0, tolerance = 1e-06, lazy_threshold = 0.01,
          tip_error = 0.00349243, cost = 349.006 },
    },
}
