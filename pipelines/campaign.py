"""The standard campaign pipeline.

Per flight::

    load -> compatibility (optional; sensor errors removed, the flight path reconstructed:
                           identify, validate, regress, frequency_id and
                           frequency_identify then use its corrected data)
         -> regress   (optional; equation-error / stepwise regression, reported)
    load -> identify -> filter    (optional)
                     -> validate
                     -> propagate (optional; a metric of the identified parameters)
                     -> infer     (optional; posterior started at the fit)
                     -> design    (optional; next manoeuvre at the identified values)
                     -> frequency (optional; empirical vs model transfer functions)
                     -> sensitivities (optional; Fisher information, Cramér-Rao bounds)
                     -> report    (the flight's engineering report)
    load -> frequency_id (optional; composite frequency responses, several windows)
                -> transfer_function  (optional; a fitted transfer function)
                -> handling_qualities (optional; bandwidth, equivalent system, margins)
         -> frequency_identify (optional; frequency-domain output/equation error)

then the aerodynamic database over every flight (optional) and one campaign report. Each ``Step`` runs a stage from
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
        # data compatibility (flight-path reconstruction): when it runs, `corrected` makes
        # the steps that read it (identify, validate, regress, frequency_id,
        # frequency_identify) use its data instead of the loaded data
        Step("compatibility", inputs={"data": "load"}, optional=True),
        Step("regress", inputs={"data": "load", "corrected": "compatibility"}, optional=True),
        Step("identify", inputs={"data": "load", "corrected": "compatibility"}),
        Step("filter", inputs={"data": "load", "parameters": "identify"}, optional=True),
        Step(
            "validate",
            inputs={"data": "load", "corrected": "compatibility", "parameters": "identify"},
        ),
        Step("propagate", inputs={"result": "identify"}, optional=True),
        Step("infer", inputs={"data": "load", "initial": "identify"}, optional=True),
        Step("design", inputs={"values": "identify", "data": "load"}, optional=True),
        Step(
            "frequency",
            stage="frequency_response",
            inputs={"data": "load", "parameters": "identify"},
            optional=True,
        ),
        Step("sensitivities", inputs={"data": "load", "values": "identify"}, optional=True),
        Step(
            "frequency_id",
            stage="composite_response",
            inputs={"data": "load", "corrected": "compatibility"},
            optional=True,
        ),
        Step("transfer_function", inputs={"response": "frequency_id"}, optional=True),
        Step(
            "frequency_identify",
            stage="frequency_domain_identify",
            inputs={"data": "load", "corrected": "compatibility"},
            optional=True,
        ),
        Step("handling_qualities", inputs={"response": "frequency_id"}, optional=True),
        Step(
            "report",
            inputs={
                "data": "load",
                "validation": "validate",
                "identification": "identify",
                "propagation": "propagate",
                "filtering": "filter",
                "inference": "infer",
                "experiment": "design",
                "frequency": "frequency",
                "compatibility": "compatibility",
                "regression": "regress",
                "composite_response": "frequency_id",
                "transfer_function": "transfer_function",
                "frequency_domain": "frequency_identify",
                "handling_qualities": "handling_qualities",
            },
        ),
    ),
    campaign_steps=(
        # optional: the aerodynamic database over every flight (aeroid.aerodynamic_database)
        Step("database", inputs={"data": "load", "identification": "identify"}, optional=True),
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
                "handling_qualities": "handling_qualities",
            },
        ),
    ),
)
