"""Interop: fitted models into renderers (Mitsuba 3, pbrt-v4), checked by rendering, and
predicted curves as tidy tables (docs/interop.md). Measured BRDFs come in through
:mod:`veil.data.merl`."""
