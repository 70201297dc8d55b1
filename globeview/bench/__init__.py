"""Benchmarks of the globe renderer: scripted camera flights, the papers' experiments (Wang
thesis ch. 7, TREND table 1), performance budgets and a memory soak test.

Headless only (EGL); imports plugins/render/terrain/geodesy, never the Qt layer. The CLI is
`globeview bench` (globeview/cli/bench.py). Targets live in the printed output and in
docs/benchmarks.md, never in timed tests.
"""
