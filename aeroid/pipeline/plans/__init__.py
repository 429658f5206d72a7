"""The plan seam: a campaign's config read and checked, and every task with its
key computed from the config alone (`plan`), ready for the run, which asks for
all it starts from in one call (`run_plan.plan_run`)."""
