"""Throughput of the builtin engine on one and two threads, against LIGGGHTS; prints JSON.

Two cases, quartz L_i = 0.02 m at full grain size:
- standard: a = 1 (~2,450 grains), the case of the engine's first throughput benchmark;
- full_scale: the measured column, a = 6 (~14,700 grains).
For each: the settle and --duration t* of collapse on 1 and on 2 threads (particle-steps/s and the
speed-up), the settle's cost in t* of collapse, and LIGGGHTS 3.8 on the same packing over
--liggghts-duration t*, with the project's deck (one layer of spheres) and a plain 2D deck
(`dimension 2`, `fix enforce2d`), and the ratios. Then the whole measured column at full scale,
settled and collapsed over 4 t* on 2 threads at each --full-run-steps (dt / contact time: the
default 1/50 and 1/25, the settle's step 2.5x the collapse's; target: under 5 minutes, moonshot 3),
and where a single-thread collapse spends its time (neighbour lists, forces, integration, output).

Ratios are measured in this run, one after the other; run it on an otherwise idle machine.

    python benchmarks/builtin_engine.py [--duration 0.25] [--liggghts-duration 0.1] [--full-run-duration 4]
"""

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numba as nb
import numpy as np

from dem.case import CollapseCase
from dem.collapse import simulate_collapse, state_from_packing
from dem.engines import get_engine
from dem.forces import ContactLaw, _forces
from dem.integrate import _move, frame_steps, record, run
from dem.neighbours import build_pairs
from dem.packing import blowup_box, settle_column, walls_open
from dem.runout import RunoutMethod
from dem.trajectory import write_trajectory

CASES = {"standard": 1.0, "full_scale": 6.0}  # aspect ratio a; quartz, L_i = 0.02 m, size_scale 1
TARGET_SPEEDUP, TARGET_FULL_RUN_S, MOONSHOT_FULL_RUN_S = 1.7, 300.0, 180.0


def column(aspect_ratio: float, duration: float) -> CollapseCase:
    return CollapseCase("quartz", 0.02, aspect_ratio, 0.39, 0.54, duration_over_tstar=duration, name="benchmark")


@nb.njit
def _forces_times(times, *args):
    for _ in range(times):
        _forces(*args)


@nb.njit
def _move_times(times, *args):
    for _ in range(times):
        _move(*args)


def repeated(compiled_loop, args: tuple, times: int) -> float:
    """Mean seconds of one call over `times` calls made in compiled code (a call from Python costs
    more than the kernel itself on small columns)."""
    compiled_loop(1, *args)
    start = time.perf_counter()
    compiled_loop(times, *args)
    return (time.perf_counter() - start) / times


def timed(function, *args, **kwargs):
    start = time.perf_counter()
    out = function(*args, **kwargs)
    return out, time.perf_counter() - start


def plain_2d(deck: str, data: str) -> tuple[str, str]:
    """The project's LIGGGHTS deck as a plain 2D one: `dimension 2`, a periodic z and `fix
    enforce2d`. A 2D per-atom density is mass per area, so it is set to rho 2d / 3 to keep the
    sphere's mass (the inertia is then the disc's: the throughput is what is compared)."""
    for old, new in (
        ("dimension       3", "dimension       2"),
        ("boundary        f fm f", "boundary        f fm p"),
        ("processors      * * 1\n", ""),
        ("fix integrate   all nve/sphere", "fix integrate   all nve/sphere\nfix planar      all enforce2d"),
    ):
        deck = deck.replace(old, new)
    lines = data.splitlines()
    body = lines.index("Atoms") + 2
    for k in range(body, len(lines)):
        fields = lines[k].split()
        if len(fields) == 7:
            fields[3] = repr(float(fields[3]) * 2.0 / 3.0 * float(fields[2]))
            lines[k] = " ".join(fields)
    return deck, "\n".join(lines) + "\n"


def liggghts_speeds(case: CollapseCase, packing, scratch: Path) -> dict:
    """particle-steps/s of LIGGGHTS' loop on the project's deck and on the plain 2D deck."""
    from dem.engines.liggghts import DATA, loop_time

    engine = get_engine("liggghts")
    project = engine.simulate(case, packing, scratch / "project")
    deck_path = engine.render(case, packing, scratch / "plain_2d")
    deck, data = plain_2d(deck_path.read_text(), (deck_path.parent / DATA).read_text())
    deck_path.write_text(deck)
    (deck_path.parent / DATA).write_text(data)
    engine.run(deck_path)
    plain = loop_time(deck_path.parent / engine.log_file)
    return {
        "version": engine.version(),
        "project_deck": project.attrs["particle_steps_per_second"],
        "plain_2d_deck": plain["particle_steps_per_second"],
    }


def where_time_goes(case: CollapseCase, packing) -> dict:
    """Seconds of a single-thread collapse by part (forces, integration, neighbour lists, output):
    the run goes frame by frame, and after each frame the force kernel, the move and a pair-list
    build are timed on copies of that frame's state; their mean cost per call times the run's
    steps (builds) gives each part's share of the measured wall time."""
    state = state_from_packing(case, packing)
    law_case = ContactLaw.from_case(case)
    law, box = law_case.as_array(), blowup_box(case)
    walls = walls_open(case)
    walls_array = np.array(walls + (0.0,) * (5 - len(walls)))
    steps_per_frame, dt = frame_steps(case.frame_interval, case.time_step)
    n = case.n_particles
    force, torque, load = np.empty((n, 2)), np.empty(n), np.empty(n)
    inv_mass, inv_inertia = 1.0 / state.mass, 1.0 / state.inertia
    per_call = {"forces": [], "integration": [], "neighbour_lists": []}
    wall = 0.0
    for _ in range(1, case.n_frames):
        _, seconds = timed(run, state, law_case, walls, box, dt, steps_per_frame)
        wall += seconds
        start, partner, history = state.pairs
        x, v, spin, wall_history = state.x.copy(), state.v.copy(), state.spin.copy(), state.wall_history.copy()
        history = history.copy()
        args = (x, v, spin, state.radius, state.mass, start, partner, history, wall_history, law, walls_array)
        per_call["forces"].append(repeated(_forces_times, args + (state.time, dt, 9.81, force, torque, load), 20))
        move = (0, n, x, v, spin, force, torque, inv_mass, inv_inertia, x.copy(), 1.0, dt)
        per_call["integration"].append(repeated(_move_times, move, 20))
        _, seconds = timed(build_pairs, state.x, state.radius, state.skin, *state.pairs)
        per_call["neighbour_lists"].append(seconds)
    steps = steps_per_frame * (case.n_frames - 1)
    trajectory = simulate_collapse(case.replace(duration_over_tstar=0.2), packing)
    with tempfile.TemporaryDirectory() as scratch:
        _, write_s = timed(write_trajectory, Path(scratch) / "t.h5", trajectory)
    parts = {
        "forces": np.mean(per_call["forces"]) * steps,
        "integration": np.mean(per_call["integration"]) * steps,
        "neighbour_lists": np.mean(per_call["neighbour_lists"]) * state.rebuilds,
        "output_hdf5": write_s * case.n_frames / trajectory.n_frames,
    }
    parts["rest"] = wall - sum(parts.values())
    parts = {k: round(float(v), 2) for k, v in parts.items()}
    return parts | {"collapse_wall_s": round(wall, 2), "rebuilds": state.rebuilds}


def measure_case(name: str, aspect_ratio: float, args, scratch: Path) -> dict:
    case = column(aspect_ratio, args.duration)
    out = {"n_particles": case.n_particles, "collapse_duration_tstar": args.duration}
    packing = None
    for threads in (1, 2):
        packing_t, settle_s = timed(settle_column, case, threads=threads)
        packing = packing if packing is not None else packing_t  # both thread counts collapse one packing
        state = state_from_packing(case, packing)
        steps, dt = frame_steps(case.frame_interval, case.time_step)
        (_, stats), wall = timed(
            record,
            state,
            ContactLaw.from_case(case),
            walls_open(case),
            blowup_box(case),
            case.time_step,
            case.frame_interval,
            case.n_frames,
            threads=threads,
        )
        per_tstar = stats.wall_time / args.duration
        out[f"threads_{threads}"] = {
            "settle_s": round(settle_s, 2),
            "settle_steps": int(packing_t.attrs["settle_steps"]),
            "collapse_s": round(stats.wall_time, 2),
            "particle_steps_per_second": round(stats.particle_steps_per_second),
            "settle_cost_in_tstar_of_collapse": round(settle_s / per_tstar, 3),
        }
        if threads == 1:
            out["time_breakdown_1_thread"] = where_time_goes(case, packing)
        print(f"{name}: {threads} thread(s) done: {out[f'threads_{threads}']}", flush=True, file=sys.stderr)
    one, two = out["threads_1"]["particle_steps_per_second"], out["threads_2"]["particle_steps_per_second"]
    out["speedup_2_threads"] = round(two / one, 3)
    if not args.skip_liggghts:
        short = case.replace(duration_over_tstar=args.liggghts_duration)
        ligg = liggghts_speeds(short, packing, scratch / name)
        out["liggghts"] = {k: (round(v) if isinstance(v, float) else v) for k, v in ligg.items()}
        out["ratio_builtin_1_thread_over_liggghts_plain_2d"] = round(one / ligg["plain_2d_deck"], 3)
        out["ratio_builtin_1_thread_over_liggghts_project_deck"] = round(one / ligg["project_deck"], 3)
        out["ratio_builtin_2_threads_over_liggghts_plain_2d"] = round(two / ligg["plain_2d_deck"], 3)
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=0.25, help="collapse t* of the throughput runs")
    parser.add_argument("--liggghts-duration", type=float, default=0.1, help="collapse t* of the LIGGGHTS runs")
    parser.add_argument("--full-run-duration", type=float, default=4.0, help="t* of the full-scale run (0: skip it)")
    # the default step and the coarser one whose answers lie within the packing scatter
    # (benchmarks/time_step.py); each settles the same poured lattice at its own settle step
    parser.add_argument("--full-run-steps", default="0.02,0.04", help="dt / contact time of the full-scale runs")
    parser.add_argument("--cases", default="standard,full_scale")
    parser.add_argument("--skip-liggghts", action="store_true")
    args = parser.parse_args()
    simulate_collapse(column(1.0, 0.1).replace(L_i=0.005), threads=1)  # compile first
    simulate_collapse(column(1.0, 0.1).replace(L_i=0.005), threads=2)
    result = {
        "benchmark": "builtin_engine",
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
        "load_average_1min_at_start": round(os.getloadavg()[0], 2),
    }
    with tempfile.TemporaryDirectory() as scratch:
        for name in [c for c in args.cases.split(",") if c]:  # --cases "": the full-scale run alone
            result[name] = measure_case(name, CASES[name], args, Path(scratch))
    if args.full_run_duration > 0:
        for step in (float(s) for s in args.full_run_steps.split(",")):
            case = column(CASES["full_scale"], args.full_run_duration).replace(dt_over_contact_time=step)
            packing, settle_s = timed(settle_column, case, threads=2)  # its step follows the collapse's
            trajectory, collapse_s = timed(simulate_collapse, case, packing, threads=2)
            total = settle_s + collapse_s
            t, runout = RunoutMethod().curve(trajectory)
            result[f"full_scale_run_2_threads_dt_tc_over_{1 / step:g}"] = {
                "n_particles": case.n_particles,
                "duration_tstar": args.full_run_duration,
                "dt_over_contact_time": step,
                "settle_s": round(settle_s, 1),
                "collapse_s": round(collapse_s, 1),
                "total_s": round(total, 1),
                "particle_steps_per_second": round(trajectory.attrs["particle_steps_per_second"]),
                # the settle against the mean cost of 1 t* of this whole collapse (the throughput runs'
                # settle_cost_in_tstar_of_collapse is against their first, cheapest t*: the column is
                # in the air, and a step costs about its touching pairs)
                "settle_cost_in_mean_tstar_of_this_collapse": round(settle_s * args.full_run_duration / collapse_s, 3),
                "runout_at": {f"{x:g}": round(float(np.interp(x, t, runout)), 3) for x in (1, 2, 3.5, 4) if x <= t[-1]},
                "target_s": TARGET_FULL_RUN_S,
                "meets_target": total < TARGET_FULL_RUN_S,
                "meets_moonshot": total < MOONSHOT_FULL_RUN_S,
            }
    result["load_average_1min_at_end"] = round(os.getloadavg()[0], 2)
    if "full_scale" in result:
        result["meets_speedup_target"] = result["full_scale"]["speedup_2_threads"] >= TARGET_SPEEDUP
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
