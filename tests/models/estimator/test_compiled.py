"""The numba-compiled streaming step against the NumPy kernels it stands in for, and the
NumPy fallback where numba is missing or switched off."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch

from wrenchd.models.estimator import compiled
from wrenchd.models.estimator.correction import Corr, CorrConfig, CorrKernel, Xfer, XferConfig
from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.estimator.pretrained import load_pretrained

numba = pytest.importorskip("numba")


@pytest.fixture(scope="module")
def seal():
    return load_pretrained("seal")


@pytest.fixture(scope="module")
def stream(free_space_session):
    js = free_space_session.joint_states
    return np.concatenate([js.position, js.velocity], axis=1)[:600]


def _numpy_kernel(model, monkeypatch):
    monkeypatch.setenv(compiled.ENV, "0")
    kernel = model.kernel()
    monkeypatch.delenv(compiled.ENV)
    assert kernel._compiled is None
    return kernel


def _run(kernel, x, batch=1):
    """Step ``kernel`` through ``x`` (T, 12), the same rows in ``batch`` parallel streams
    (the later ones shifted so that they differ); (T, batch, 6) outputs."""
    state = kernel.initial_state(batch)
    out = []
    for k in range(len(x)):
        rows = np.stack([x[(k + 37 * b) % len(x)] for b in range(batch)])
        y, state = kernel.step(rows, state)
        out.append(y)
    return np.array(out)


def test_tanh_within_a_few_float32_units_of_the_exact_value():
    from wrenchd.models.estimator.compiled_kernels import tanh32

    x = np.linspace(-12.0, 12.0, 200_001).astype(np.float32)
    got = np.array([tanh32(v) for v in x[::97]] + [tanh32(np.float32(v)) for v in
                                                   (0.0, 1e-6, -1e-6, 7.9, 30.0, -30.0)])
    x = np.concatenate([x[::97], np.float32([0.0, 1e-6, -1e-6, 7.9, 30.0, -30.0])])
    exact = np.tanh(x.astype(np.float64))
    ulp = np.spacing(np.abs(exact).astype(np.float32)).astype(np.float64)
    assert (np.abs(got - exact) / ulp).max() <= 8.0
    assert np.abs(got).max() <= 1.0


@pytest.mark.parametrize("batch", [1, 3])
def test_compiled_step_equals_numpy_kernel(seal, stream, monkeypatch, batch):
    fast, slow = seal.kernel(), _numpy_kernel(seal, monkeypatch)
    assert fast._compiled is not None
    a, b = _run(fast, stream, batch), _run(slow, stream, batch)
    assert np.abs(b).max() > 0.5                    # real outputs, not zeros on both sides
    np.testing.assert_allclose(a, b, rtol=0, atol=2e-5 * np.abs(b).max())


def test_compiled_stacked_layers_equal_numpy_kernel(seal, stream, monkeypatch):
    """Xfer: the step-1 LSTMs, then layers of its own (per-group inputs), then heads."""
    torch.manual_seed(3)
    xfer = Xfer(XferConfig.for_base(seal), seal).eval()
    with torch.no_grad():
        for p in xfer.parameters():
            p.add_(0.05 * torch.randn_like(p))
    fast, slow = xfer.kernel(), _numpy_kernel(xfer, monkeypatch)
    assert fast._compiled is not None and len(fast.layers) > 1
    a, b = _run(fast, stream[:200], 2), _run(slow, stream[:200], 2)
    np.testing.assert_allclose(a, b, rtol=0, atol=2e-5 * np.abs(b).max())


def test_float64_kernels_stay_on_numpy():
    model = FreeSpaceModel().double()
    assert model.kernel()._compiled is None


def test_compiled_correction_equals_numpy(seal, stream, monkeypatch):
    torch.manual_seed(5)
    corr = Corr(CorrConfig()).eval()
    w = corr.window
    windows = np.stack([stream[k:k + w] for k in range(0, 300, 7)])
    step1 = seal.predict_sequence(stream[:300])[::7][:len(windows)].astype(np.float32)
    corr.set_normalisation(windows.reshape(-1, windows.shape[-1]), step1)
    fast = corr.kernel()
    monkeypatch.setenv(compiled.ENV, "0")
    slow = corr.kernel()
    assert fast._compiled is not None and slow._compiled is None
    one = np.concatenate([fast.correct(windows[i:i + 1], step1[i:i + 1])
                          for i in range(len(windows))])
    ref = slow.correct(windows, step1)
    assert np.abs(ref - step1).max() > 1e-3             # the net corrects something
    np.testing.assert_allclose(one, ref, rtol=0, atol=1e-5 * np.abs(ref).max())
    assert one.dtype == np.float32
    # the batched path of the compiled kernel is NumPy's
    np.testing.assert_array_equal(fast.correct(windows, step1), ref)


def test_corr_kernel_from_state_is_compiled_too(seal):
    corr = Corr(CorrConfig()).eval()
    state = corr.state_arrays()
    assert CorrKernel.from_state(state, corr.window)._compiled is not None


@pytest.mark.parametrize("how", ["switched off", "missing"])
def test_numpy_fallback_in_a_fresh_process(how):
    """Without numba (its import failing) or with WRENCHD_NUMBA=0 the estimator runs on the
    NumPy kernels, and the numbers are theirs."""
    hide = "import sys; sys.modules['numba'] = None\n" if how == "missing" else ""
    code = hide + (
        "import numpy as np\n"
        "from wrenchd.models.estimator.pretrained import load_pretrained\n"
        "from wrenchd.models.estimator import compiled\n"
        "k = load_pretrained('seal').kernel()\n"
        "assert k._compiled is None, 'compiled kernel built'\n"
        "y, _ = k.step(np.ones((1, 12)), k.initial_state(1))\n"
        "print(compiled.numba_wanted(), float(np.abs(y).sum()))\n")
    env = {**os.environ, compiled.ENV: "0"} if how == "switched off" else None
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    wanted, total = out.stdout.split()
    assert wanted == ("False" if how == "switched off" else "True")
    assert float(total) > 0.0


def test_kernels_travel_without_their_compiled_form(seal):
    """Pickled (to a worker, back from one): the compiled form is rebuilt where the kernel
    lands, so a process without numba still takes it, and copies step alike."""
    import copy
    import pickle

    kernel = seal.kernel()
    blob = pickle.dumps(kernel)
    assert b"numba" not in blob
    again = pickle.loads(blob)
    assert again._compiled is not None and again._compiled is not kernel._compiled
    x = np.ones((1, 12))
    for other in (again, copy.deepcopy(kernel)):
        np.testing.assert_array_equal(other.step(x, other.initial_state(1))[0],
                                      kernel.step(x, kernel.initial_state(1))[0])
    corr = Corr(CorrConfig()).eval().kernel()
    blob = pickle.dumps(corr)
    assert b"numba" not in blob and pickle.loads(blob)._compiled is not None


def test_kernels_built_in_a_deferred_block_compile_on_first_use(seal, stream):
    """Inside ``deferred_compilation`` (a replay) kernels are built, unpickled and copied
    without their compiled form; the first streaming step or one-row correction builds it,
    and the numbers are those of a kernel compiled when built. Closing the block (nested
    or not) leaves the process as it found it."""
    import pickle

    eager = seal.kernel()
    corr = Corr(CorrConfig()).eval()
    with compiled.deferred_compilation():
        with compiled.deferred_compilation():
            pass
        assert not compiled.compile_now()                 # still deferred after a nested one
        lazy = seal.kernel()
        lazy_corr = corr.kernel()
        unpickled = pickle.loads(pickle.dumps(eager))
    assert compiled.compile_now()
    for kernel in (lazy, lazy_corr, unpickled):
        assert kernel._compiled is compiled.DEFERRED
    x = stream[:50]
    np.testing.assert_array_equal(_run(lazy, x), _run(eager, x))
    assert lazy._compiled is not None and lazy._compiled is not compiled.DEFERRED
    windows = np.stack([stream[:corr.window]])
    step1 = np.zeros((1, 6), np.float32)
    np.testing.assert_array_equal(lazy_corr.correct(windows, step1),
                                  corr.kernel().correct(windows, step1))
    assert lazy_corr._compiled is not compiled.DEFERRED
    # a batch never builds it (the batched path is NumPy's)
    with compiled.deferred_compilation():
        batch_only = corr.kernel()
    batch_only.correct(np.repeat(windows, 2, axis=0), np.zeros((2, 6), np.float32))
    assert batch_only._compiled is compiled.DEFERRED


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() != 0 or not shutil.which("setpriv"),
                    reason="needs root and setpriv to run a process as another user")
def test_compiled_where_nothing_next_to_the_module_is_writable():
    """A hardened service (read-only system, no home): numba cannot cache next to the module
    nor in the user's cache, and would refuse to define the kernels; they are cached under
    the temporary directory instead, and the estimator runs compiled."""
    code = ("from wrenchd.models.estimator.pretrained import load_pretrained\n"
            "k = load_pretrained('seal').kernel()\n"
            "print(k._compiled is not None)\n")
    import tempfile
    from pathlib import Path

    tmp = Path(tempfile.mkdtemp(prefix="wrenchd-test-"))      # pytest's own is root's alone
    tmp.chmod(0o1777)
    env = {"PATH": os.environ.get("PATH", ""), "HOME": "/nonexistent", "TMPDIR": str(tmp),
           "OMP_NUM_THREADS": "1"}
    out = subprocess.run(["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups",
                          sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, timeout=300, cwd="/")
    if out.returncode != 0 and "Permission denied" in out.stderr:
        pytest.skip("the checkout is not readable by another user")
    try:
        assert out.returncode == 0, out.stderr
        assert out.stdout.split() == ["True"]
        assert list(tmp.glob("wrenchd-numba-65534/**/*.nbi"))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
