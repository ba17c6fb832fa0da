"""fuseplan planner core: scenarios, cost, spherical PSO, ant-colony fusion, baselines, smoothing, checks."""
