"""Building blocks below every method: the numerics policy (:mod:`.numerics`) and static
capacities with overflow retry (:mod:`.capacity`). Nothing here knows about shadows."""
