"""The report of a step-1 medium fitted over colour channels (issue 30): its design hint reads
a parameter per channel (``tau[r]``) as the family's (``tau``).

The result is validation/results/rgb_medium.json, step 1 of validation/rgb_table.py over the
path-traced RGB sessions (forward-series, three channels); no engine runs here."""

from __future__ import annotations

import dataclasses
import os

from veil.fitting import FitResult

MEDIUM = os.path.join(os.path.dirname(__file__), "..", "validation", "results", "rgb_medium.json")


def test_report_of_a_medium_over_channels():
    med = FitResult.from_json(MEDIUM)
    assert med.channel_names == ("r", "g", "b")
    text = med.report()  # raised ParameterError ('tau[r]') before
    assert "tau[r]" in text and "[[Hint]]" not in text
    # a loose optical depth in one channel is named as the result names it
    loose = dataclasses.replace(med, stderr=dict(med.stderr, **{"tau[g]": 0.5}), stderr_total=None)
    hint = loose.report().split("[[Hint]]")[1]
    assert "tau[g] uncertain" in hint
    assert "specular peak" in hint
