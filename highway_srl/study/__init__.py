"""The paper's study: many runs and what is made of them (a layer above experiments/).

jobs.py (scenes, methods, budgets: the study as a list of training jobs), runner.py (runs the jobs and resumes),
executors.py (one job; local worker processes or Ray), chunks.py (a study run in seed chunks, read as one),
results.py (the jobs' results, read and checked), table.py (the table type), tables.py, seed_tables.py, figures.py, stats.py and verdicts.py (the claims checked against the paper, the
seed as the unit), report.py, paper_numbers.py (the paper's tables, typed in), transfer.py (train in ours, deploy in
SUMO and highway-env: one table). Each job is one experiments.train run plus its experiments.evaluate.
"""
