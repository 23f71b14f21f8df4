"""Reporting: the published numbers of both papers, evaluation tables, and the results page
that src.report builds from one long DataFrame of every evaluation (frame.py)."""
