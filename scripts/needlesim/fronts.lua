-- Measured speed-against-accuracy fronts: written by tools/speed_accuracy.py (do not edit;
-- docs/performance.md). Per scenario, the Pareto-optimal settings, cheapest first: tip_error
-- is the largest tip distance from the converged reference run [m], cost the median step
-- time per simulated second [ms/s] on the project's 2-core machine.
return {
    brachytherapy = {
        { label = "dt=0.02 lazy=0.05 tol=1e-06", dt = 0.02, refine = 1.0, tolerance = 1e-06, lazy_threshold = 0.05,
          tip_error = 0.000396175, cost = 973.817 },
        { label = "dt=0.02", dt = 0.02, refine = 1.0, tolerance = 1e-08, lazy_threshold = 0.01,
          tip_error = 0.000356869, cost = 1100.47 },
        { label = "tol=0.0001", dt = 0.01, refine = 1.0, tolerance = 0.0001, lazy_threshold = 0.01,
          tip_error = 0.000298022, cost = 1872.83 },
        { label = "tol=1e-06", dt = 0.01, refine = 1.0, tolerance = 1e-06, lazy_threshold = 0.01,
          tip_error = 0.000295933, cost = 2104.08 },
        { label = "lazy=0.05", dt = 0.01, refine = 1.0, tolerance = 1e-08, lazy_threshold = 0.05,
          tip_error = 0.000266589, cost = 2138.51 },
        { label = "dt=0.005", dt = 0.005, refine = 1.0, tolerance = 1e-08, lazy_threshold = 0.01,
          tip_error = 1.88197e-05, cost = 4441.09 },
    },
    phantom = {
        { label = "dt=0.02 lazy=0.05 tol=0.0001", dt = 0.02, refine = 1.0, tolerance = 0.0001, lazy_threshold = 0.05,
          tip_error = 0.0102413, cost = 149.691 },
        { label = "tol=0.0001", dt = 0.01, refine = 1.0, tolerance = 0.0001, lazy_threshold = 0.01,
          tip_error = 0.00967791, cost = 283.163 },
        { label = "dt=0.005", dt = 0.005, refine = 1.0, tolerance = 1e-08, lazy_threshold = 0.01,
          tip_error = 0.00510429, cost = 628.521 },
    },
}
