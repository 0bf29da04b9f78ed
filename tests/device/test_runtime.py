"""Which OpenCL runtime (exabricks.device.runtime, issue 53 item 2): the system's
drivers, else Intel's CPU runtime that `pip install 'exabricks[cpu]'` brings into
the environment, without root; and, in a fresh venv that sees no system driver, the
wheel of `make wheel` with the cpu extra, its demo rendered through it as through PoCL."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from exabricks.device import runtime
from exabricks.film.image_io import read_image
from helpers import GERRIS, ROOT, assert_one_error_line, run_cli
from helpers.pictures import assert_visible_png


@pytest.fixture
def fresh(monkeypatch, tmp_path):
    """runtime's choice made afresh, with no OCL_ICD_* variable and an empty system
    folder of ICD files unless a test fills it."""
    saved = dict(os.environ)  # prepare() sets variables for the processes it starts
    monkeypatch.setattr(runtime, "_CHOSEN", None)
    for name in ("OCL_ICD_VENDORS", "OCL_ICD_FILENAMES", runtime.INTEL_VECTORIZER):
        os.environ.pop(name, None)
    vendors = tmp_path / "vendors"
    vendors.mkdir()
    os.environ["EXABRICKS_SYSTEM_OPENCL_VENDORS"] = str(vendors)
    yield vendors
    os.environ.clear()
    os.environ.update(saved)


def test_a_system_driver_wins(fresh, monkeypatch, tmp_path):
    (fresh / "pocl.icd").write_text("libpocl.so.2\n")
    prefix = tmp_path / "env"
    (prefix / "lib").mkdir(parents=True)
    (prefix / runtime.PYPI_CPU_RUNTIME).write_bytes(b"")
    monkeypatch.setattr(sys, "prefix", str(prefix))
    chosen = runtime.prepare()
    assert chosen.source == "system" and "pocl.icd" in chosen.detail
    assert "OCL_ICD_VENDORS" not in os.environ
    assert os.environ[runtime.INTEL_VECTORIZER] == "1"


def test_without_a_driver_the_environment_s_cpu_runtime_is_used(fresh, monkeypatch, tmp_path):
    prefix = tmp_path / "env"
    (prefix / "lib").mkdir(parents=True)
    (prefix / runtime.PYPI_CPU_RUNTIME).write_bytes(b"")
    monkeypatch.setattr(sys, "prefix", str(prefix))
    chosen = runtime.prepare()
    assert chosen.source == "pypi-cpu"
    assert os.environ["OCL_ICD_VENDORS"] == str(prefix / runtime.PYPI_CPU_RUNTIME)
    assert runtime.prepare() is chosen  # once per process


def test_what_the_user_set_is_kept(fresh, monkeypatch):
    monkeypatch.setenv("OCL_ICD_VENDORS", "/opt/vendors")
    monkeypatch.setenv(runtime.INTEL_VECTORIZER, "16")
    chosen = runtime.prepare()
    assert chosen.source == "environment" and chosen.detail == "OCL_ICD_VENDORS=/opt/vendors"
    assert os.environ[runtime.INTEL_VECTORIZER] == "16"


def test_nothing_found_says_how_to_get_a_runtime(fresh, monkeypatch, tmp_path):
    monkeypatch.setattr(sys, "prefix", str(tmp_path))
    monkeypatch.setattr(sys, "base_prefix", str(tmp_path))
    chosen = runtime.prepare()
    assert chosen.source == "none" and "pip install 'exabricks[cpu]'" in chosen.why


def test_nothing_found_through_a_variable_names_it_and_what_it_hides(fresh, monkeypatch, tmp_path):
    monkeypatch.setenv("OCL_ICD_VENDORS", str(tmp_path / "nothing"))
    message = runtime.none_found()
    assert f"OCL_ICD_VENDORS={tmp_path / 'nothing'}" in message and "install" in message
    (fresh / "pocl.icd").write_text("libpocl.so.2\n")
    message = runtime.none_found("device")
    assert message.startswith(f"no OpenCL device found through OCL_ICD_VENDORS={tmp_path / 'nothing'}")
    assert f"hides the system's drivers ({fresh}: pocl.icd): unset it" in message


def test_devices_without_a_driver_through_ocl_icd_vendors_keeps_its_first_line(tmp_path):
    """OCL_ICD_VENDORS naming a folder with no usable driver while the system has one:
    the error named neither, and `devices` dropped its line saying which runtime."""
    empty, system = tmp_path / "empty", tmp_path / "system"
    empty.mkdir()
    system.mkdir()
    (system / "pocl.icd").write_text("libpocl.so.2\n")
    proc = run_cli("devices", env={"OCL_ICD_VENDORS": str(empty),
                                   "EXABRICKS_SYSTEM_OPENCL_VENDORS": str(system)})
    assert proc.stdout == f"OpenCL runtime: OCL_ICD_VENDORS is set: the loader reads what it " \
                          f"names (OCL_ICD_VENDORS={empty})\n"
    assert_one_error_line(proc, f"OCL_ICD_VENDORS={empty}", f"{system}: pocl.icd", "unset it")


def test_devices_says_which_runtime_and_why(cli):
    proc = cli("devices", check=0)
    assert proc.stdout.startswith("OpenCL runtime: ")
    rows = __import__("json").loads(cli("devices", "--json", check=0).stdout)
    assert rows and all(r["runtime"] in ("system", "environment", "pypi-cpu") for r in rows)


@pytest.mark.slow
def test_a_fresh_venv_without_root_renders_the_demo(tmp_path):
    """The wheel that `make wheel` builds (exabricks is not on PyPI), installed with
    the `cpu` extra into a new venv (no system site packages), with no system driver
    visible: `devices` names Intel's runtime from PyPI, the wheel's own embedded
    plume renders from a folder outside the checkout, and the demo's frame equals
    PoCL's (where the suite runs) within float rounding. The extra's packages come
    from PyPI, or offline from $EXABRICKS_WHEELHOUSE (a folder of downloaded wheels:
    `pip download -d DIR "dist/exabricks-*.whl[cpu]"` once) where it is set."""
    dist = tmp_path / "dist"
    made = subprocess.run(["make", "-C", str(ROOT), "--no-print-directory", "-o", f"{sys.prefix}/.installed-run",
                           "wheel", f"VENV={sys.prefix}", f"DIST={dist}"],
                          capture_output=True, text=True, timeout=600)
    assert made.returncode == 0, made.stderr
    wheel = next(dist.glob("exabricks-*.whl"))
    assert made.stdout.strip().splitlines()[-1] == str(wheel)
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    house = os.environ.get("EXABRICKS_WHEELHOUSE")
    offline = ["--no-index", "--find-links", house] if house else []
    subprocess.run([str(venv / "bin" / "pip"), "install", "-q", *offline, f"{wheel}[cpu]"], check=True,
                   timeout=1200)
    empty = tmp_path / "no-vendors"
    empty.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("OCL_ICD", "PYTHONPATH", "EXABRICKS_DEVICE"))}
    env.update(EXABRICKS_SYSTEM_OPENCL_VENDORS=str(empty), EXABRICKS_CACHE=str(tmp_path / "cache"))
    exe = venv / "bin" / "exabricks"
    devices = subprocess.run([str(exe), "devices"], capture_output=True, text=True, env=env, timeout=300,
                             cwd=tmp_path)
    assert devices.returncode == 0, devices.stderr
    assert "Intel's CPU runtime from PyPI" in devices.stdout.splitlines()[0], devices.stdout
    assert "Intel(R) OpenCL" in devices.stdout
    # the embedded plume as the wheel installed it, from a folder outside the checkout
    script = ("import exabricks as eb, pathlib; p = pathlib.Path(eb.__file__).parent / 'data/gerris-plume'; "
              "assert not p.resolve().is_relative_to(pathlib.Path(sys.argv[1]).resolve()); "
              "eb.render(eb.open(p / 'plume7-1.cells'), field='T', colormap='inferno', size=(64, 48))"
              ".save('embedded.png')")
    proc = subprocess.run([str(venv / "bin" / "python"), "-c", f"import sys; {script}", str(ROOT)],
                          capture_output=True, text=True, env=env, timeout=900, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert_visible_png(tmp_path / "embedded.png")
    flags = ["--field", "T", "--size", 96, 72]
    out = tmp_path / "intel.exr"
    proc = subprocess.run([str(exe), "render", str(GERRIS), "-o", str(out), *map(str, flags)],
                          capture_output=True, text=True, env=env, timeout=900, cwd=tmp_path)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    run_cli("render", GERRIS, "-o", tmp_path / "pocl.exr", *flags, check=0)
    intel, meta = read_image(out)
    pocl, _ = read_image(tmp_path / "pocl.exr")
    assert "pthread" not in meta["settings"]["device"]  # PoCL's CPU device is "pthread-..."
    assert float(pocl[..., 3].max()) > 0.1
    np.testing.assert_allclose(intel, pocl, atol=1e-4)
