"""The built-in stages, registered in one place.

`stages` holds the contract (`Stage`, `StageContext`, the `STAGES` registry);
the modules imported here define aeroid's own stages on top of it and register
them as they load. `aeroid.pipeline` imports this module, so every built-in
stage is in `STAGES` before any pipeline is resolved. A new built-in stage's
module is added to the list below.
"""

from __future__ import annotations

# the order sets the order of `STAGES` (and of every listing drawn from it)
# isort: off
from . import library_stages
from . import analysis_stages
from . import database_stage
from . import campaign_report
# isort: on

__all__ = ["BUILTIN_MODULES"]

BUILTIN_MODULES = (library_stages, analysis_stages, database_stage, campaign_report)
