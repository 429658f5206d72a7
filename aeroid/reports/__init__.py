"""Figures and reports: plots, HTML and Markdown reports."""
