"""`vswrist sweep`: grids of training + evaluation trials, and hyperparameter search, on Ray Tune.

`spec` reads and checks a sweep file (no Ray needed), `trial` runs one trial with the functions of `vswrist train`
and `vswrist evaluate` (no Ray needed), `summary` writes `vswrist compare`'s tables and plots for a whole grid,
`best` writes a searched entry into a hyperparameter file, and `tune_runner` puts the trials on Ray.
Ray is the optional extra `pip install -e ".[sweep]"`.
"""

RAY_INSTALL_HINT = 'vswrist sweep needs Ray Tune and Optuna: pip install -e ".[sweep]"  (ray[tune]==2.60.0, optuna)'
