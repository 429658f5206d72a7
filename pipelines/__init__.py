"""Pipeline definitions selected by campaign configs (``pipeline: campaign``).

Each module defines a module-level ``pipeline`` (an `aeroid.pipeline.Pipeline`).
Copy `campaign.py` to start a pipeline of your own.
"""
