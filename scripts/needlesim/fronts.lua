-- Measured speed-against-accuracy fronts: written by tools/speed_accuracy.py (do not edit;
-- docs/performance.md). Per scenario, the Pareto-optimal settings, cheapest first: tip_error
-- is the largest tip distance from the converged reference run [m], cost the median step
-- time per simulated second [ms/s] on the project's 2-core machine.
return {
    brachytherapy = {
        { label = "dt=0.02", dt = 0.02, refine = 1.0, tolerance = 1e-08, lazy_threshold = 0.01,
          tip_error = 0.000356868, cost = 1565.51 },
        { label = "default", dt = 0.01, refine = 1.0, tolerance = 1e-08, lazy_threshold = 0.01,
          tip_error = 0.000296028, cost = 3004.03 },
        { label = "lazy=0.05", dt = 0.01, refine = 1.0, tolerance = 1e-08, lazy_threshold = 0.05,
          tip_error = 0.000266589, cost = 4182.39 },
        { label = "dt=0.005", dt = 0.005, refine = 1.0, tolerance = 1e-08, lazy_threshold = 0.01,
          tip_error = 1.88197e-05, cost = 7199.18 },
    },
    phantom = {
        { label = "dt=0.02 lazy=0.05 tol=0.0001", dt = 0.02, refine = 1.0, tolerance = 0.0001, lazy_threshold = 0.05,
          tip_error = 0.0102407, cost = 197.076 },
        { label = "tol=0.0001", dt = 0.01, refine = 1.0, tolerance = 0.0001, lazy_threshold = 0.01,
          tip_error = 0.00967775, cost = 404.511 },
        { label = "dt=0.005", dt = 0.005, refine = 1.0, tolerance = 1e-08, lazy_threshold = 0.01,
          tip_error = 0.00510417, cost = 879.89 },
    },
}
