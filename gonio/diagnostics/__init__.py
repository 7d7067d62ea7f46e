"""Diagnostics: run time against error (:mod:`~gonio.diagnostics.bench`) and numerical stress
(:mod:`~gonio.diagnostics.stress`, its pipeline stages in
:mod:`~gonio.diagnostics.stress_stages`). They exercise the rest of gonio; nothing imports them.
"""
