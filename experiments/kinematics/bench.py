"""The kinematics learning benchmark (thesis chapter 2): runs its parts and writes the report.

:class:`KinematicsBenchSettings` holds the options of ``mcpilco-bench-kinematics`` (their
meaning: :mod:`mcpilco.experiments.kinematics.parts`). :func:`run_benchmark` runs the parts
asked for, keeps the others from an earlier ``kinematics.json`` when merging, and writes
``kinematics.json``, ``kinematics.md`` and the PNG plots
(:mod:`mcpilco.experiments.kinematics.report`). :func:`run_fk_seed_study` runs part (c)
alone over several seeds and writes ``kinematics_c_seeds.{json,md}``.
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcpilco.experiments.infra.sweep import SweepRunner
from mcpilco.experiments.kinematics.parts import (
    FACING_CONE,
    VISIBILITY_CONE,
    controller_part,
    fk_gp_part,
    fk_seed_study,
    identify_ur10,
    monte_carlo,
    noise_vs_samples,
    true_structure,
    ur10_datasets,
)
from mcpilco.experiments.kinematics.report import fk_seed_markdown, markdown_report, plot_results
from mcpilco.experiments.results import Headline, Result, ResultLayout, read_result, write_result

__all__ = [
    "PART_KEYS",
    "QUICK",
    "KinematicsBenchSettings",
    "run_benchmark",
    "run_fk_seed_study",
]

# result keys of the parts a, b, c, d
PART_KEYS = ("monte_carlo", "noise_vs_samples", "fk_gp", "controller")
# tiny sizes of a smoke run (--quick)
QUICK = dict(
    robots=4, samples=600, sizes=(25, 100, 300, 600), repeats=1, ctrl_train=150, online_rounds=1
)


@dataclass(frozen=True)
class KinematicsBenchSettings:
    """Options of a benchmark run (the command-line defaults).

    ``parts``: a subset of ``"abcd"``. (a) ``robots``. (b) ``samples`` frames per UR10
    trajectory (also for c, d), ``sizes`` its prefixes, ``repeats`` trajectories. (c)
    ``fk_train`` samples picked by ``train_selection``. (d) ``ctrl_train`` samples picked by
    ``ctrl_selection``, FK model ``ctrl_model``, ``online_rounds`` refits, ``ctrl_steps``
    controller updates, ``ctrl_starts`` extra starts, ``ctrl_unlimited`` (no clipping to the
    data's joint box), ``ctrl_orientation``, ``ctrl_refine``, ``ctrl_hold`` frames at rest,
    ``rotation_outputs``. (b-d) waypoints ``home +- span``, the marker protocol
    ``facing_cone`` / ``visibility_cone`` [deg, None: off]. (c, d) ``noise_scale`` on the env's
    noise, ``measurement`` ``"ideal"`` (noise model) or ``"aruco"`` (rendered, parts a and c).
    """

    parts: str = "abcd"
    robots: int = 64
    samples: int = 2100
    sizes: tuple[int, ...] = (25, 50, 100, 200, 400, 800, 1300, 2100)
    repeats: int = 1
    fk_train: int = 100
    ctrl_train: int = 300
    train_selection: str = "design"
    ctrl_selection: str = "random"
    ctrl_model: str = "end"
    online_rounds: int = 3
    ctrl_steps: int = 300
    ctrl_starts: int = 4
    ctrl_unlimited: bool = False
    ctrl_orientation: str = "ypr"
    ctrl_refine: str = "both"
    ctrl_hold: int = 5
    rotation_outputs: str = "five"
    span: float = 1.0
    facing_cone: float | None = FACING_CONE
    visibility_cone: float | None = VISIBILITY_CONE
    noise_scale: float = 1.0
    measurement: str = "ideal"
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.parts or set(self.parts) - set("abcd"):
            raise ValueError(f"parts must be a subset of 'abcd', got {self.parts!r}")
        if self.measurement not in ("ideal", "aruco"):
            raise ValueError(f"measurement must be 'ideal' or 'aruco', got {self.measurement!r}")
        if self.measurement == "aruco" and set(self.parts) & set("bd"):
            raise ValueError(
                "measurement 'aruco' supports parts a and c only: (b) counts misclassified "
                "triplets over all 126 and (d) measures every reached pose, and both need the "
                "markers seen in every frame"
            )

    def quick(self) -> KinematicsBenchSettings:
        """These settings with the tiny sizes of :data:`QUICK`."""
        return dataclasses.replace(self, **QUICK)


def _identification(s: KinematicsBenchSettings, data: dict[str, Any], res: dict[str, Any]):
    """Identify the structure on ``D_tr``, record it in ``res``; the structure parts (c) and
    (d) use (the true one when identification failed)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        idn = identify_ur10(data)
    structure = idn["structure"]
    res["identification"] = dict(
        samples=int(data["train"][0].shape[0]),
        correct=idn["correct"],
        joint_types=None if structure is None else structure.joint_types,
        markers=None if structure is None else list(structure.markers),
        joints=None if structure is None else list(structure.joints),
        seconds=idn["seconds"],
        dropped_frames=idn.get("dropped_frames"),
        error=idn.get("error"),
    )
    if not idn["correct"]:  # fall back to the true structure so (c)/(d) still run
        structure = true_structure(data["env"])
        res["identification"]["note"] = "identification failed; (c)/(d) use the true structure"
    return structure


def run_benchmark(
    settings: KinematicsBenchSettings,
    out_dir: str | Path,
    command: str,
    merge: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """Run ``settings.parts`` and write ``kinematics.json``, ``kinematics.md`` and the plots
    under ``out_dir``; returns the result dictionary.

    ``command`` is recorded with the result and with each part it produced. With ``merge``,
    the parts not run are kept from an existing ``out_dir/kinematics.json`` (each with the
    command that produced it); without it they are dropped.
    """
    s = settings
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    res: dict[str, Any] = dict(
        command=command, seed=s.seed, span=s.span, noise_scale=s.noise_scale,
        measurement=s.measurement,
    )  # fmt: skip
    old_json = out / "kinematics.json"
    if merge and old_json.exists():
        old = read_result(old_json).payload()
        for key in (*PART_KEYS, "identification"):
            if key in old:
                if key != "identification":
                    old[key].setdefault("command", old.get("command", ""))
                res[key] = old[key]
    for key, part in zip(PART_KEYS, "abcd", strict=True):
        if part in s.parts:
            res.pop(key, None)  # recomputed below
    t0 = time.perf_counter()
    ideal = s.measurement == "ideal"  # the rendered path has its own markers (ur10_datasets)
    protocol = dict(
        facing_cone=s.facing_cone if ideal else None,
        visibility_cone=s.visibility_cone if ideal else None,
    )
    if "a" in s.parts:
        res["monte_carlo"] = monte_carlo(s.robots, s.seed, progress)
    if "b" in s.parts:
        sizes = tuple(n for n in s.sizes if n <= s.samples) or (s.samples,)
        res["noise_vs_samples"] = noise_vs_samples(
            s.seed, s.samples, sizes, s.repeats, progress, s.span, s.facing_cone,
            s.visibility_cone,
        )  # fmt: skip
        res["noise_vs_samples"]["marker_protocol"] = protocol
    if "c" in s.parts or "d" in s.parts:
        data = ur10_datasets(
            s.seed, s.samples, s.span, s.noise_scale, s.measurement, s.facing_cone,
            s.visibility_cone,
        )  # fmt: skip
        structure = _identification(s, data, res)
        if "c" in s.parts:
            res["fk_gp"] = fk_gp_part(data, structure, s.fk_train, s.seed,
                                      selection=s.train_selection)  # fmt: skip
            res["fk_gp"]["marker_protocol"] = protocol
        if "d" in s.parts:
            res["controller"] = controller_part(
                data,
                structure,
                s.ctrl_train,
                s.online_rounds,
                s.seed,
                progress,
                s.ctrl_steps,
                s.span,
                starts=s.ctrl_starts,
                limit_to_data=not s.ctrl_unlimited,
                orientation=s.ctrl_orientation,
                refine=s.ctrl_refine,
                rotation_outputs=s.rotation_outputs,
                hold=s.ctrl_hold,
                selection=s.ctrl_selection,
                fk_model=s.ctrl_model,
            )
            res["controller"]["marker_protocol"] = protocol
    for key in PART_KEYS:  # which command produced each part (merged ones keep theirs)
        if key in res:
            res[key].setdefault("command", res["command"])
    res["seconds"] = time.perf_counter() - t0
    res["paths"] = plot_results(res, out)
    res["paths"]["json"] = str(out / "kinematics.json")
    res["paths"]["markdown"] = str(out / "kinematics.md")
    write_result(res["paths"]["json"], RESULT_LAYOUTS[0], res)
    Path(res["paths"]["markdown"]).write_text(markdown_report(res))
    return res


def run_fk_seed_study(
    settings: KinematicsBenchSettings,
    seeds: list[int],
    out_dir: str | Path,
    command: str,
    runner: SweepRunner | None = None,
    runs_dir: str | Path = "runs/bench_kinematics",
    progress: bool = True,
) -> dict[str, Any]:
    """Part (c) on each of ``seeds`` (:func:`~mcpilco.experiments.kinematics.parts.fk_seed_study`,
    one result file per seed under ``runs_dir``), written to ``kinematics_c_seeds.json`` and
    ``.md`` under ``out_dir``; returns the study.

    Raises:
        RuntimeError: when a seed failed (the seeds that ran are kept for the next call).
    """
    s = settings
    study = fk_seed_study(
        seeds, s.samples, s.span, s.noise_scale, s.fk_train, s.facing_cone, s.visibility_cone,
        progress, s.train_selection, runner=runner, runs_dir=runs_dir,
    )  # fmt: skip
    study["command"] = command
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_result(out / "kinematics_c_seeds.json", RESULT_LAYOUTS[1], study)
    (out / "kinematics_c_seeds.md").write_text(fk_seed_markdown(study, command))
    return study


# -- result files and headline rows of the results index ----------------------------------

RESULT_LAYOUTS = (
    ResultLayout("kinematics", config=("seed", "span", "noise_scale", "measurement", "paths")),
    ResultLayout(
        "kinematics_seeds",
        config=("seeds", "n_train", "train_selection", "marker_protocol", "goal"),
        cases=("rows",),
    ),
)
"""The layouts of ``kinematics.json`` and ``kinematics_c_seeds.json``
(:mod:`mcpilco.experiments.results`)."""


def _mm(xs: list[float]) -> str:
    return " / ".join(f"{1e3 * x:.1f}" for x in xs) + " mm"


def _structure_row(r: Result) -> str:
    mc = r["monte_carlo"]
    return (
        f"structure identification: {mc['percent_correct']:.0f} % of {mc['triplets']} "
        f"triplets correct on {mc['robots']} random robots"
    )


def _fk_seeds_row(r: Result) -> str:
    met = r["goal"]["met_all"]
    chain = r["summary"]["chain"]["mean"][:3]
    poly = r["summary"]["polynomial"]["mean"][:3]
    n = len(r["seeds"])
    return (
        f"FK from 100 designed samples, mean RMSE: chain model {_mm(chain)} "
        f"(goal met on {met['chain']} of {n} seeds), one GP {_mm(poly)} "
        f"({met['polynomial']} of {n})"
    )


def _controller_row(r: Result) -> str:
    last = r["controller"]["rounds"][-1]
    t = last["rmse_true"]
    return (
        f"kinematic controller after {last['round']} online refits: {_mm(t[:3])}, {t[-1]:.3f} rad"
    )


def _controller_chain_row(r: Result) -> str:
    t = r["controller"]["rounds"][0]["rmse_true"]
    return f"controller on the chain model, before any refit: {_mm(t[:3])}, {t[-1]:.3f} rad"


def _seed(r: Result) -> str:
    return f"seed {r['seed']}"


HEADLINES = (
    Headline(
        "Kinematics from markers",
        "kinematics.json",
        _structure_row,
        "kinematics.md",
        seeds=lambda r: f"random robots from seed {r['seed']}",
    ),
    Headline(
        "Kinematics from markers", "kinematics_c_seeds.json", _fk_seeds_row, "kinematics_c_seeds.md"
    ),
    Headline(
        "Kinematics from markers", "kinematics.json", _controller_row, "kinematics.md", seeds=_seed
    ),
    Headline(
        "Kinematics from markers",
        "kinematics_d_chain/kinematics.json",
        _controller_chain_row,
        "kinematics_d_chain/kinematics.md",
        seeds=_seed,
    ),
)
"""The kinematics benchmark's rows of the results index."""


def replot(result: Result, json_path: Path) -> list[Path]:
    """Redraw the kinematics figures next to a ``kinematics.json`` result file (a seed study
    has no figure)."""
    if result.kind != "kinematics":
        return []
    return [Path(p) for p in plot_results(result.payload(), Path(json_path).parent).values()]
