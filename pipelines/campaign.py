"""The standard campaign pipeline.

Per flight::

    load -> identify -> filter    (optional)
                     -> validate
                     -> propagate (optional; a metric of the identified parameters)
                     -> infer     (optional; posterior started at the fit)
                     -> design    (optional; next manoeuvre at the identified values)
                     -> frequency (optional; empirical vs model transfer functions)
                     -> sensitivities (optional; Fisher information, Cramér-Rao bounds)
                     -> report    (the flight's engineering report)

then one campaign report over every flight. Each ``Step`` runs a stage from
`aeroid.pipeline.stages` and maps the stage's input roles to earlier steps;
its options come from ``stages.<step name>`` in the config. To build your own
pipeline, copy this file to ``pipelines/<name>.py`` and select it with
``pipeline: <name>`` (or ``pipeline: package.module:attribute``).
"""

from aeroid.pipeline import Pipeline, Step

pipeline = Pipeline(
    name="campaign",
    flight_steps=(
        Step("load"),
        Step("identify", inputs={"data": "load"}),
        Step("filter", inputs={"data": "load", "parameters": "identify"}, optional=True),
        Step("validate", inputs={"data": "load", "parameters": "identify"}),
        Step("propagate", inputs={"result": "identify"}, optional=True),
        Step("infer", inputs={"data": "load", "initial": "identify"}, optional=True),
        Step("design", inputs={"values": "identify"}, optional=True),
        Step("frequency", inputs={"data": "load", "parameters": "identify"}, optional=True),
        Step("sensitivities", inputs={"data": "load", "values": "identify"}, optional=True),
        Step(
            "report",
            inputs={
                "validation": "validate",
                "identification": "identify",
                "propagation": "propagate",
                "filtering": "filter",
                "inference": "infer",
                "experiment": "design",
                "frequency": "frequency",
            },
        ),
    ),
    campaign_steps=(
        Step(
            "campaign_report",
            inputs={
                "data": "load",
                "identification": "identify",
                "validation": "validate",
                "propagation": "propagate",
                "reports": "report",
                # for the detailed figures of the report
                "filtering": "filter",
                "inference": "infer",
                "experiment": "design",
                "frequency": "frequency",
            },
        ),
    ),
)
