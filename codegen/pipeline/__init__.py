"""The host side of a build composed from the stages, a window at a time: plan, tables, twin and checks."""
