#!/usr/bin/env python3
"""The house's structure, checked over `cargo metadata` (CI runs it).

1. Layers: a crate at crates/<layer>/<name> depends only on crates of its own or a lower
   layer, dev- and build-dependencies included. The order is ARCHITECTURE.md's:
   base < map < solve < io < place < front < merge < app < lab. An exception must be listed
   in ARCHITECTURE.md's "Layer exceptions" table (`| `from` | `to` | reason |`), with a
   reason.
2. Names: every crate's folder is its name without `mapmerge-`.
3. Dependencies: every declared dependency is used. A normal dependency is named in src/
   (or build.rs, or in a feature); a dev-dependency anywhere in the crate.

Exit code 0 when all hold; 1 with one line per fault otherwise.
"""

import json
import pathlib
import re
import subprocess
import sys

LAYERS = ["base", "map", "solve", "io", "place", "front", "merge", "app", "lab"]
ROOT = pathlib.Path(__file__).resolve().parent.parent


def exceptions():
    """(from, to) pairs with a reason, from ARCHITECTURE.md's "Layer exceptions" table."""
    text = (ROOT / "ARCHITECTURE.md").read_text(encoding="utf-8")
    match = re.search(r"^## Layer exceptions\n(.*?)(?=^## |\Z)", text, re.M | re.S)
    pairs = set()
    if not match:
        return pairs
    for line in match.group(1).splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 3 and cells[0].startswith("`mapmerge-"):
            if cells[2]:
                pairs.add((cells[0].strip("`"), cells[1].strip("`")))
    return pairs


def rust_text(directory, parts):
    """All .rs text below `directory`'s `parts` (files or folders)."""
    chunks = []
    for part in parts:
        path = directory / part
        files = [path] if path.is_file() else sorted(path.rglob("*.rs")) if path.is_dir() else []
        chunks.extend(f.read_text(encoding="utf-8") for f in files)
    return "\n".join(chunks)


def main():
    metadata = json.loads(
        subprocess.run(
            ["cargo", "metadata", "--format-version", "1", "--no-deps", "--offline"],
            cwd=ROOT,
            check=True,
            capture_output=True,
            text=True,
        ).stdout
    )
    allowed = exceptions()
    layer_of = {}
    directory_of = {}
    for package in metadata["packages"]:
        directory = pathlib.Path(package["manifest_path"]).parent
        relative = directory.relative_to(ROOT)
        if len(relative.parts) != 3 or relative.parts[0] != "crates":
            continue
        layer_of[package["name"]] = relative.parts[1]
        directory_of[package["name"]] = directory
    faults = []
    used_exceptions = set()
    for package in metadata["packages"]:
        name = package["name"]
        if name not in layer_of:
            continue
        layer, directory = layer_of[name], directory_of[name]
        if layer not in LAYERS:
            faults.append(f"{name}: crates/{layer} is not a layer ({' < '.join(LAYERS)})")
            continue
        if name != f"mapmerge-{directory.name}":
            faults.append(f"{name}: its folder crates/{layer}/{directory.name} is not named after it")
        features = json.dumps(package.get("features", {}))
        src = rust_text(directory, ["src", "build.rs"])
        everything = rust_text(directory, ["src", "build.rs", "tests", "benches", "examples"])
        for dep in package["dependencies"]:
            dep_name, kind = dep["name"], dep["kind"] or "normal"
            target = dep_name
            if target in layer_of:
                dep_layer = layer_of[target]
                if LAYERS.index(dep_layer) > LAYERS.index(layer):
                    if (name, target) in allowed:
                        used_exceptions.add((name, target))
                    else:
                        faults.append(
                            f"{name} ({layer}) depends on {target} ({dep_layer}), a higher layer"
                            f" ({kind}); list it with a reason in ARCHITECTURE.md's Layer exceptions"
                        )
            ident = (dep.get("rename") or dep_name).replace("-", "_")
            pattern = re.compile(r"\b" + re.escape(ident) + r"\b")
            if kind == "dev":
                if not pattern.search(everything):
                    faults.append(f"{name}: dev-dependency {dep_name} is never used")
            elif kind == "normal":
                if not pattern.search(src) and f"dep:{dep_name}" not in features and not (
                    re.search(r'"' + re.escape(dep_name) + r'/', features)
                ):
                    faults.append(f"{name}: dependency {dep_name} is not used in src/")
    for pair in sorted(allowed - used_exceptions):
        faults.append(f"ARCHITECTURE.md lists the exception {pair[0]} → {pair[1]}, which no longer exists")
    for fault in faults:
        print(fault)
    if faults:
        return 1
    print(f"layers, names and dependencies: {len(layer_of)} crates checked, no fault")
    return 0


if __name__ == "__main__":
    sys.exit(main())
