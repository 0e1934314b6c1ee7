"""The calibrated scene: the scene file with the fitted values written in, and for each
an ``assumptions:`` entry saying from which record, the value and its interval."""

from __future__ import annotations

from datetime import date
from pathlib import Path

import yaml

from flexarm_ros.errors import InputError


def _source_mapping(case) -> dict:
    """The scene's own file as loaded (its spelling kept), else the full mapping."""
    from flexarm_ros.ensemble.keys import scene_mapping
    from flexarm_ros.scene.loading import resolve_scene_path
    scene = case.scene
    if case.scene_file is None:                 # a scene changed by a spec's set:
        return scene_mapping(scene)
    try:
        return yaml.safe_load(resolve_scene_path(case.scene_file).read_text()) or {}
    except (InputError, OSError, yaml.YAMLError):
        return scene_mapping(scene)


def note(p: dict, out: dict, records: str) -> str:
    unit = f" {p['unit']}" if p["unit"] else ""
    if p["identifiable"]:
        lo, hi = p["ci95"]
        what = (f"{p['value']:.6g}{unit} ± {p['stderr']:.3g} (1σ), 95 % interval "
                f"{lo:.6g} .. {hi:.6g}")
    else:
        why = "; ".join(u["text"] for u in out["unidentifiable"] if p["key"] in u["keys"])
        what = (f"{p['value']:.6g}{unit}, NOT identifiable from these data ({why}); the "
                f"value is where the fit left it, any value along that direction fits as "
                f"well")
    return (f"Calibrated by flexarm calibrate on {records} ({date.today().isoformat()}): "
            f"{what}; bounds {p['low']:g} .. {p['high']:g}, start {p['start']:.6g}; cost "
            f"{out['cost_before']:.4g} → {out['cost_after']:.4g} over "
            f"{out['residual_count']} residuals.")


def calibrated_mapping(case, out: dict, records: str) -> dict:
    from flexarm_ros.ensemble.keys import put_keys, scene_mapping
    values = {}
    for p in out["parameters"]:
        values.update(p["sets"])
    from flexarm_ros.scene.loading import load_scene_dict
    data = _source_mapping(case)
    try:
        put_keys(data, values)
        load_scene_dict(data)                   # the file's form still valid
    except InputError:
        data = put_keys(scene_mapping(case.scene), values)
    notes = list(data.get("assumptions") or [])
    fitted = {k for p in out["parameters"] for k in p["keys"]}
    notes = [n for n in notes if not (isinstance(n, dict) and n.get("key") in fitted
                                      and str(n.get("note", "")).startswith("Calibrated by "
                                                                            "flexarm"))]
    for p in out["parameters"]:
        for k in p["keys"]:
            text = note(p, out, records)
            if p["key"] not in p["keys"]:         # a factor on the scene's values
                f = p["sets"][k] / p["value"] if p["value"] else 0.0
                se = (f" ± {p['stderr'] * f:.3g}" if p["stderr"] is not None else "")
                text = (f"{k} = {p['sets'][k]:.6g}{se} (1σ): the scene's value {f:.6g} × the "
                        f"factor {p['key']}. " + text)
            notes.append({"key": k, "note": text})
    data["assumptions"] = notes
    load_scene_dict(data)
    return data


def write_scenes(problem, out: dict, target, spec: bool) -> list[Path]:
    parts = sorted({c.record for c in problem.cases if c.record})
    feats = [f.metric for c in problem.cases for f in c.features]
    if feats:
        parts.append("the targets " + ", ".join(dict.fromkeys(feats)))
    records = " and ".join(parts)
    paths = []
    for case in problem.cases:
        data = calibrated_mapping(case, out, records)
        path = Path(target) / f"{case.name}.yaml" if spec else Path(target)
        if spec:
            path.parent.mkdir(parents=True, exist_ok=True)
        text = (f"# {case.scene.name} calibrated by flexarm calibrate (see assumptions)\n"
                + yaml.safe_dump(data, sort_keys=False, allow_unicode=True, width=90))
        tmp = path.with_name(path.name + ".part")
        tmp.write_text(text)
        tmp.replace(path)
        paths.append(path)
        if not spec:
            break
    return paths
