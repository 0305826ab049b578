-- Measured speed-against-accuracy fronts: written by tools/speed_accuracy.py (do not edit;
-- docs/performance.md). Per scenario, the Pareto-optimal settings, cheapest first: tip_error
-- is the largest tip distance from the converged reference run [m], cost the median step
-- time per simulated second [ms/s] on the project's 2-core machine.
return {
    brachytherapy = {
        { label = "dt=0.02 lazy=0.05 tol=1e-06", dt = 0.02, refine = 1.0, tolerance = 1e-06, lazy_threshold = 0.05,
          tip_error = 0.000396166, cost = 2038.58 },
        { label = "dt=0.02", dt = 0.02, refine = 1.0, tolerance = 1e-08, lazy_threshold = 0.01,
          tip_error = 0.000370151, cost = 2542.1 },
        { label = "lazy=0.05", dt = 0.01, refine = 1.0, tolerance = 1e-08, lazy_threshold = 0.05,
          tip_error = 0.000266589, cost = 3713.18 },
        { label = "dt=0.005", dt = 0.005, refine = 1.0, tolerance = 1e-08, lazy_threshold = 0.01,
          tip_error = 0.000259729, cost = 9644.62 },
    },
    phantom = {
        { label = "dt=0.02 lazy=0.05 tol=0.0001", dt = 0.02, refine = 1.0, tolerance = 0.0001, lazy_threshold = 0.05,
          tip_error = 0.00697294, cost = 257.644 },
        { label = "dt=0.005", dt = 0.005, refine = 1.0, tolerance = 1e-08, lazy_threshold = 0.01,
          tip_error = 0.0045675, cost = 1099.11 },
    },
}
