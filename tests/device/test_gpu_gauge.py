"""The kernels stay within their NVIDIA register, stack and spill budgets,
measured offline by ../shared/tools/gpu-proxy (benchmarks/gpu_gauge.py; issue 51).
`make test-gauge` runs it; .ci/run installs the gauge where the shared tools are."""

from __future__ import annotations

import pytest

from benchmarks import gpu_gauge

pytestmark = pytest.mark.gauge


@pytest.mark.skipif(not (gpu_gauge.GAUGE / "ptx_proxy.sh").exists(),
                    reason=f"no gpu-proxy at {gpu_gauge.GAUGE}")
def test_every_kernel_entry_within_its_budget():
    assert gpu_gauge.available(), f"gpu-proxy not set up: run {gpu_gauge.GAUGE / 'setup.sh'}"
    figures, _ = gpu_gauge.measure()
    assert not gpu_gauge.over_budget(figures), gpu_gauge.over_budget(figures)


def test_over_budget_names_what_grew():
    key = ("N_FIELDS=1", "eb_render")  # the GPU default
    figures = {k: v for k, v in gpu_gauge.BUDGETS.items()}
    assert gpu_gauge.over_budget(figures) == []
    figures[key] = (figures[key][0] + 1, figures[key][1], 0)
    assert len(gpu_gauge.over_budget(figures)) == 1 and "registers" in gpu_gauge.over_budget(figures)[0]
    del figures[key]
    assert "not measured" in gpu_gauge.over_budget(figures)[0]
