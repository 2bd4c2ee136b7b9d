"""Shared fixtures: ``LIVETRACK_KERNELS`` switched within a test takes effect.

:func:`livetrack.estimator.edge_kernels.kernels` caches the choice it reads from the environment; here every test
starts with it forgotten, and ``monkeypatch.setenv`` / ``delenv`` of ``LIVETRACK_KERNELS`` (and their undoing)
make it read again."""

from __future__ import annotations

import os

if os.environ.get("PYTEST_XDIST_WORKER"):  # a pytest-xdist worker (``-n auto``): the workers share the cores, so
    for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # one BLAS thread each (set
        os.environ.setdefault(_name, "1")  # before numpy loads its BLAS; two threads each ran 2-3x longer)

import pytest  # noqa: E402

from livetrack.estimator import edge_kernels  # noqa: E402


@pytest.fixture
def monkeypatch(monkeypatch):
    """pytest's ``monkeypatch``, whose setenv/delenv of ``LIVETRACK_KERNELS`` reset the cached kernel choice."""
    setenv, delenv = monkeypatch.setenv, monkeypatch.delenv

    def setenv_reset(name, value, prepend=None):
        setenv(name, value, prepend)
        if name == edge_kernels.KERNELS_ENV:
            edge_kernels.reset_kernels()

    def delenv_reset(name, raising=True):
        delenv(name, raising)
        if name == edge_kernels.KERNELS_ENV:
            edge_kernels.reset_kernels()

    monkeypatch.setenv, monkeypatch.delenv = setenv_reset, delenv_reset
    yield monkeypatch
    monkeypatch.undo()
    edge_kernels.reset_kernels()


@pytest.fixture(autouse=True)
def _kernel_choice_read_afresh():
    edge_kernels.reset_kernels()
    yield
    edge_kernels.reset_kernels()

