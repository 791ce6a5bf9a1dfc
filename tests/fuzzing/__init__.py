"""A fuzz suite of our own (issue 28): mutated G-code and job files run in-process through `plan`'s pipeline in
forked workers under time and memory limits; each failure reduced to a signature and shrunk to its smallest input.

corpus.py reads the seeds (tests/data/gcode/**, the example jobs), gcode_mutations.py and job_mutations.py change
them, inputs.py makes input k of a seed, outcomes.py runs one input and classifies it, pool.py runs inputs in
forked workers, shrink.py shrinks a failing input, campaign.py puts it together for scripts/fuzz.py.
"""
