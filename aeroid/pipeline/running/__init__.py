"""The run seam: tasks -> statuses. The runner prunes what is stored, hands the
rest to an executor, and each task's execution puts its result in the store
in one call (`storage.commits.put`) with the stage's work done in another
(`stages.work.perform`)."""
