"""Motion: the program's items as segments, lookahead and the planner, and the ideal time of every step event."""
