"""Simulator against twin: the image run in simavr or s51 and every pulse compared with the tables' prediction."""
