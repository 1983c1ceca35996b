"""Benchmarks on real measurements: EMPS (:mod:`drafttwin.benchmarks.emps`)."""
