"""Single runs, each behind one CLI command: train.py (a training run folder, resumable; its scalars.csv and
TensorBoard log: training_log.py, its metrics.json numbers: training_metrics.py), evaluate.py
(deployment metrics of a run, on our simulator or a foreign backend), renderings.py (render, the demo's
episode), play.py (a person drives), bench.py, demo.py (what `make run` runs), policy.py (load a trained policy),
runs.py (run folders, atomic files, provenance). The study that combines many runs is highway_srl.study.
"""
