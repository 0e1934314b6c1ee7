"""Closed-form oracles used by the tests only (never by the model): ``beam_theory`` holds
the characteristic equations of the clamped-free beam, the beam with a rigid tip body and
the beam on a free hub."""
