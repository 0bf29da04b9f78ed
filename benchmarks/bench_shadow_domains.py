"""The shadow integrator's cached transmittance under a memory budget that splits the
data into domains (docs/design-rendering.md, "Lights and shadows"; issue 62).

    .venv/bin/python -m benchmarks.bench_shadow_domains [--size N] [--domains N] [--only KEY] [--write-docs]

Each shared dataset's default picture under `--integrator shadow` at SIZE², 1
sample per pixel, drawn under the smallest memory budget whose domains each
hold at most 1/DOMAINS of the data (the light's cached transmittance takes a
quarter of it, budget_bytes.LIGHT_SHARE), and in memory. Every domain adds its
part of the transmittance to one volume; "RMSE, same volume" compares the
budget's frame with the in-memory frame whose volume has the budget's size (the
sum over domains against the whole: what the domains change), "RMSE, in memory"
with the in-memory default (a volume of up to 64 MiB: what the budget's smaller
volume changes), both of the developed RGBA. At budgets of 256 MiB and more the
volume is the in-memory one.
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks import benchdoc

TITLE = "Shadows under a memory budget (PoCL)"


def budget(ds, scene, domains: int) -> int:
    """The budget whose domains each hold at most 1/`domains` of the data
    (tests/helpers/streaming.py's budget_for, over one opened dataset)."""
    from exabricks.engine.domains import domain_bytes, domain_plan
    from exabricks.engine.budget_bytes import LIGHT_SHARE, SLACK, fixed_bytes, light_bytes

    bricks, regions, _ = ds.structures()
    plan = domain_plan(bricks, regions, [-np.inf] * 3, [np.inf] * 3, 0.0, True, ("b", "r"))
    bare = fixed_bytes(scene, bricks.n_bricks) + SLACK * domain_bytes(bricks, regions, plan,
                                                                      scene.fields()) / domains
    return int(bare + light_bytes(scene, bare / (1.0 - LIGHT_SHARE))) + 1


def measure(dataset, size: int, domains: int) -> dict:
    import exabricks as eb
    from exabricks.engine import light_volume
    from exabricks.engine.renderer import Renderer
    from exabricks.engine.streaming import Budgeted, render_steps

    ds = eb.open(dataset.path, fields=[dataset.field], **({"format": "yt"} if dataset.key == "enzo" else {}))
    scene = eb.Renderer(ds).scene(field=dataset.field, size=(size, size), integrator="shadow")
    bricks, regions, bvh = ds.structures()
    limit = budget(ds, scene, domains)
    split = Budgeted(bricks, regions, scene, limit)
    got = render_steps(split, scene)

    def in_memory(**light):
        return Renderer(bricks, regions, bvh, fields=(dataset.field,),
                        light=light_volume.Cache(**light)).render_scene(scene).rgba

    def rmse(a, b):
        return float(np.sqrt(np.mean((a.astype(np.float64) - b) ** 2)))

    return {"budget": limit, "domains": split.n_domains, "nodes": got.stats["light_volume"]["nodes"],
            "mib": got.stats["light_volume"]["bytes"] / 2**20,
            "same": rmse(got.rgba, in_memory(max_bytes=split.light_bytes)),
            "memory": rmse(got.rgba, in_memory())}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    benchdoc.add_common_args(parser, runs=1)
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--domains", type=int, default=8)
    args = parser.parse_args(argv)
    sets = benchdoc.datasets()
    body = [__doc__.split("\n\n", 2)[2].strip(), "",
            f"{benchdoc.machine(opencl=True)}; `python -m benchmarks.bench_shadow_domains --size "
            f"{args.size} --domains {args.domains}`.", "",
            "| dataset | budget | domains | nodes | volume MiB | RMSE, same volume | RMSE, in memory |",
            "|---|---:|---:|---|---:|---:|---:|"]
    for key in benchdoc.chosen(args.only, ["gerris", "amrex", "athena", "enzo"]):
        got = measure(sets[key], args.size, args.domains)
        print(key, got, flush=True)
        body.append(f"| {sets[key].name} | {benchdoc.fmt_bytes(got['budget'])} | {got['domains']} | "
                    f"{'x'.join(map(str, got['nodes']))} | {got['mib']:.2f} | {got['same']:.1e} | "
                    f"{got['memory']:.1e} |")
    benchdoc.publish(TITLE, "\n".join(body), args.write_docs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
