-- Measured speed-against-accuracy fronts: written by tools/speed_accuracy.py (do not edit;
-- docs/performance.md). Per scenario, the Pareto-optimal settings, cheapest first: tip_error
-- is the largest tip distance from the converged reference run [m], cost the median step
-- time per simulated second [ms/s] on the project's 2-core machine.
return {
    brachytherapy = {
        { label = "dt=0.04 lazy=0.05 tol=1e-06", dt = 0.04, refine = 1.0, tolerance = 1e-06, lazy_threshold = 0.05,
          tip_error = 0.00123101, cost = 793.863 },
        { label = "dt=0.04", dt = 0.04, refine = 1.0, tolerance = 1e-08, lazy_threshold = 0.01,
          tip_error = 0.00082095, cost = 944.632 },
        { label = "dt=0.02 lazy=0.05 tol=1e-06", dt = 0.02, refine = 1.0, tolerance = 1e-06, lazy_threshold = 0.05,
          tip_error = 0.000437006, cost = 1580.07 },
        { label = "dt=0.02", dt = 0.02, refine = 1.0, tolerance = 1e-08, lazy_threshold = 0.01,
          tip_error = 0.000371654, cost = 1675.3 },
        { label = "dt=0.005", dt = 0.005, refine = 1.0, tolerance = 1e-08, lazy_threshold = 0.01,
          tip_error = 0.000218399, cost = 5895.91 },
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
