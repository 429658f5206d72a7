"""The run seam: tasks -> statuses. The runner starts from one call into the plan
seam (`plans.run_plan.plan_run`), prunes what is stored, hands the rest to an
executor, and each task's execution puts its result in the store in one call
(`storage.commits.put`) with the stage's work done in another
(`stages.work.perform`); it ends with one call into the stages seam
(`stages.run_outputs.write_run_outputs`)."""
