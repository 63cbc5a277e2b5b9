"""The paper's study: many runs and what is made of them (a layer above experiments/).

jobs.py (scenes, methods, budgets: the study as a list of training jobs), runner.py (runs the jobs with an
executor, local worker processes or Ray, and resumes), tables.py, figures.py, report.py (claims checked
against the paper), paper_numbers.py (the paper's tables, typed in), transfer.py (train in ours, deploy in
SUMO and highway-env: one table). Each job is one experiments.train run plus its experiments.evaluate.
"""
