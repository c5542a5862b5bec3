"""Strict test settings (STYLE.md §11): rank promotion raises, strict dtype
promotion for the numerics modules, a ``getkey`` fixture, and an ``x64``
fixture for numerics tests that need double precision."""

from __future__ import annotations

import itertools

import jax
import jax.random as jr
import numpy as np
import pytest

jax.config.update("jax_numpy_rank_promotion", "raise")
jax.config.update("jax_numpy_dtype_promotion", "standard")


@pytest.fixture
def strict_dtype_promotion():
    """Run the test under strict dtype promotion: mixing float32 and float64
    (or int and float arrays) without an explicit cast raises.  The numerics
    modules use it for every test (``pytestmark``)."""
    with jax.numpy_dtype_promotion("strict"):
        yield


@pytest.fixture
def getkey():
    """Return a function that hands out fresh, deterministic PRNG keys."""
    counter = itertools.count()
    base = jr.PRNGKey(0)

    def _getkey():
        return jr.fold_in(base, next(counter))

    return _getkey


@pytest.fixture
def rng():
    """A seeded NumPy generator for reference computations."""
    return np.random.default_rng(1234)


@pytest.fixture
def x64():
    """Run the test with 64-bit floats; restores the previous setting afterwards."""
    previous = jax.config.read("jax_enable_x64")
    jax.config.update("jax_enable_x64", True)
    try:
        yield
    finally:
        jax.config.update("jax_enable_x64", previous)
