"""Cross play (`aquarium-warp eval --cross-play`): every prey spec against every predator spec, globs
such as `run/model_*.pt` expanded to every checkpoint in training order (`expand_specs`); the pairs run
through `evaluate.evaluate_policies`, and the result adds `[prey][predator]` matrices (mean and std over
seeds) of captures per prey, reward per prey and per predator, and prey survival (the fraction of prey
not captured in an episode), Elo ratings fitted to the survival matrix (`elo_ratings`); `write_cross_play`
writes them (CSV/JSON), `plots.plot_cross_play` draws a heatmap.
"""

from __future__ import annotations

import csv
import glob
import json
import math
import os
import re

import numpy as np

from ..atomic import atomic_open
from ..config import AquariumConfig
from ..drivers import common_world, is_heuristic
from ..records import json_safe
from .evaluate import PROVENANCE_KEYS, evaluate_policies, parse_spec, summarize, write_results

CROSS_PLAY_METRICS = ("captures_per_prey", "reward_per_prey", "reward_per_predator", "prey_survival")


def expand_specs(specs) -> list[str]:
    """Specs with glob patterns (e.g. `run/model_*.pt`, optionally `LABEL=run/model_*.pt`) replaced by
    the files they match, in natural order (model_2 before model_10), each labelled by its file name
    (`LABEL/model_2` under a label). Other specs stay as they are."""
    out = []
    for spec in specs:
        label, value = parse_spec(spec)
        if is_heuristic(value) or os.path.exists(value) or not glob.has_magic(value):
            out.append(spec)
            continue
        paths = glob.glob(value)
        if not paths:
            raise ValueError(f"policy spec {spec!r}: no file matches the pattern")

        def natural(path):
            return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", os.path.basename(path))]

        for path in sorted(paths, key=natural):
            name = os.path.splitext(os.path.basename(path))[0]
            out.append(f"{label}/{name}={path}" if spec != value else f"{name}={path}")
    return out


def cross_play(
    prey,
    predator,
    env: AquariumConfig | None = None,
    episodes: int = 200,
    seeds=(0,),
    device=None,
    max_worlds: int = 1024,
    deterministic: bool = True,
    progress=None,
    rating: bool = True,
    blind_to: dict[str, str] | None = None,
) -> dict:
    """Every prey spec against every predator spec (globs expanded by `expand_specs`) under the
    evaluation protocol of `evaluate_policies` (which plays the pairs). `env=None`: the common world of
    the trained policies (`drivers.common_world`), else docs/model.md's.

    Returns `evaluate_policies`' result plus `"cross_play"`: the row (prey) and column (predator)
    labels and, per metric of `CROSS_PLAY_METRICS`, `[prey][predator]` matrices of the mean and std over
    seeds of the per-seed means. `prey_survival` is the fraction of the `prey_count` first prey slots
    not captured in an episode. With `rating`, `"rating"`: `elo_ratings` of that survival matrix.
    `blind_to`: the neighbour ablation of `evaluate_policies`."""
    prey, predator = (
        expand_specs([prey] if isinstance(prey, str) else prey),
        expand_specs([predator] if isinstance(predator, str) else predator),
    )
    if env is None:
        env = common_world(prey + predator, AquariumConfig())
    result = evaluate_policies(
        prey,
        predator,
        env,
        episodes=episodes,
        seeds=seeds,
        device=device,
        max_worlds=max_worlds,
        deterministic=deterministic,
        progress=progress,
        blind_to=blind_to,
    )
    rows = list(dict.fromkeys(parse_spec(p)[0] for p in prey))
    cols = list(dict.fromkeys(parse_spec(p)[0] for p in predator))
    by_pair = {(r["prey_policy"], r["predator_policy"]): r for r in result["summary"]}
    survival: dict[tuple[str, str], dict[int, list[float]]] = {}
    for record in result["episodes"]:
        alive = [c == 0 for c in record["prey_captures"][: env.prey_count]]
        survival.setdefault((record["prey_policy"], record["predator_policy"]), {}).setdefault(
            record["seed"], []
        ).append(sum(alive) / len(alive))
    matrices = {}
    for metric in CROSS_PLAY_METRICS:
        mean, std = np.zeros((len(rows), len(cols))), np.zeros((len(rows), len(cols)))
        for i, a in enumerate(rows):
            for j, b in enumerate(cols):
                if metric == "prey_survival":
                    s = summarize(list(survival[(a, b)].values()))
                    mean[i, j], std[i, j] = s["mean"], s["std_over_seeds"]
                    by_pair[(a, b)].update(prey_survival_mean=s["mean"], prey_survival_std=s["std_over_seeds"])
                else:
                    mean[i, j], std[i, j] = by_pair[(a, b)][f"{metric}_mean"], by_pair[(a, b)][f"{metric}_std"]
        matrices[metric] = {"mean": mean.tolist(), "std": std.tolist()}
    result["cross_play"] = {"prey": rows, "predator": cols, "matrices": matrices}
    if rating:
        games = len(result["protocol"]["seeds"]) * episodes * env.prey_count
        prey_r, pred_r = elo_ratings(np.array(matrices["prey_survival"]["mean"]), games)
        result["rating"] = {
            "basis": "prey_survival",
            "games_per_pair": games,
            "prey": dict(zip(rows, prey_r.tolist())),
            "predator": dict(zip(cols, pred_r.tolist())),
        }
    return result


def elo_ratings(score: np.ndarray, games, mean: float = 1500.0, iterations: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """Elo-scale ratings of row players (prey) and column players (predators) from `score[i, j]`, the
    row player's expected score against column player j (here: prey survival), each pair over `games`
    games (a number or a matrix). Maximum likelihood of the Elo model `score = 1 / (1 + 10 **
    ((R_col - R_row) / 400))` (Bradley-Terry with soft outcomes) by Newton's method; only rating
    differences are identified, so the ratings are shifted to average `mean`. Scores of exactly 0 or 1
    are moved half a game inward, which keeps the ratings finite."""
    score = np.asarray(score, dtype=np.float64)
    if score.ndim != 2 or score.size == 0 or not np.all((score >= 0) & (score <= 1)):
        raise ValueError(f"score must be a non-empty matrix of values in [0, 1], got shape {score.shape}")
    n = np.broadcast_to(np.asarray(games, dtype=np.float64), score.shape)
    if not np.all(n > 0):
        raise ValueError("games must be > 0 for every pair")
    score = np.clip(score, 0.5 / n, 1 - 0.5 / n)
    P, Q = score.shape
    k = math.log(10) / 400
    signs = np.zeros((P, Q, P + Q))  # d(R_row - R_col) / dR
    signs[np.arange(P)[:, None], np.arange(Q)[None, :], np.arange(P)[:, None]] = 1
    signs[np.arange(P)[:, None], np.arange(Q)[None, :], P + np.arange(Q)[None, :]] = -1
    r = np.zeros(P + Q)
    for _ in range(iterations):
        expected = 1 / (1 + np.exp(-k * (signs @ r)))
        gradient = k * np.einsum("pq,pqr->r", n * (score - expected), signs)
        weight = k * k * n * expected * (1 - expected)
        hessian = np.einsum("pq,pqr,pqs->rs", weight, signs, signs)
        # The Hessian is singular along the common shift; the least-norm step leaves that shift alone.
        step = np.linalg.lstsq(hessian, gradient, rcond=None)[0]
        r += step
        if np.max(np.abs(step)) < 1e-9:
            break
    r += mean - r.mean()
    return r[:P], r[P:]


def write_cross_play(result: dict, out_dir: str) -> dict[str, str]:
    """`write_results`' files plus `cross_play.csv` (one row per prey/predator pair: means and stds over
    seeds) and `cross_play.json` (labels, matrices, rating, protocol) into `out_dir`."""
    paths = write_results(result, out_dir)
    cp = result["cross_play"]
    paths["cross_play_csv"] = os.path.join(out_dir, "cross_play.csv")
    paths["cross_play_json"] = os.path.join(out_dir, "cross_play.json")
    with atomic_open(paths["cross_play_csv"], newline="") as f:
        writer = csv.writer(f)
        columns = [(m, s) for m in CROSS_PLAY_METRICS for s in ("mean", "std")]
        writer.writerow(["prey_policy", "predator_policy"] + [f"{m}_{s}" for m, s in columns])
        for i, a in enumerate(cp["prey"]):
            for j, b in enumerate(cp["predator"]):
                writer.writerow([a, b] + [cp["matrices"][m][s][i][j] for m, s in columns])
    with atomic_open(paths["cross_play_json"]) as f:
        json.dump(
            json_safe(
                {
                    **cp,
                    "rating": result.get("rating"),
                    "protocol": result["protocol"],
                    **{k: result[k] for k in PROVENANCE_KEYS if k in result},
                }
            ),
            f,
            indent=1,
        )
    return paths
