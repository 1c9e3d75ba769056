-- 0012 (plans): the 3-D view of an execution draws it in its plan's scene, found by the
-- execution's id (`store::plans::of_execution`); without this index that lookup scans every plan.
CREATE INDEX plans_by_execution ON plans (execution_id);
