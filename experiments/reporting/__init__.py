"""What the experiments' reports share: statistics of the stored rows, markdown tables,
figures, the papers' values and the integrity section.

Each module has one job: :mod:`~attopt.experiments.reporting.statistics` (RMS,
ratios to bounds, NEES and the integrity statistic; also used by the
experiments' summary columns), :mod:`~attopt.experiments.reporting.tables`
(markdown), :mod:`~attopt.experiments.reporting.figures` (figures through
:mod:`attopt.solvers.plotting`), :mod:`~attopt.experiments.reporting.paper_values`
(each experiment's ``paper_values.toml``) and
:mod:`~attopt.experiments.reporting.integrity` (the integrity section of every report).
"""
