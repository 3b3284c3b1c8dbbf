"""Statistics over results: pairwise comparisons, aggregates across tasks, and curves as text and PNG."""
