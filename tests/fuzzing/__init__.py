"""A fuzz suite of our own (issue 28): mutated G-code and job files run in-process through `plan`'s pipeline in
forked workers under time and memory limits; each failure reduced to a signature and shrunk to its smallest input.

corpus.py reads the seeds (tests/data/gcode/**, the example jobs), gcode_mutations.py and job_mutations.py change
them, inputs.py makes input k of a seed, outcomes.py plans one input in-process and names its outcome, pool.py
runs inputs in forked workers, campaign.py puts it together (shrinking included) for scripts/fuzz.py.
"""
