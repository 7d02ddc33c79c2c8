"""A pure-Python wheel (PEP 427) written from its files' texts, for the tests that pip-install a
plugin from outside the tree (tests/device_plugin.py, tests/controller_plugin.py): the
``WHEEL`` and ``RECORD`` files added, no build backend, no network."""
from __future__ import annotations

import base64
import hashlib
import zipfile
from pathlib import Path


def write(directory: Path, name: str, version: str, files: dict[str, str], generator: str) -> Path:
    """The wheel ``name``-``version`` holding ``files`` (path in the wheel -> text; its
    ``.dist-info`` METADATA and entry points among them) in ``directory``."""
    dist = f"{name}-{version}.dist-info"
    files = {**files, f"{dist}/WHEEL": f"Wheel-Version: 1.0\nGenerator: {generator}\nRoot-Is-Purelib: true\n"
                                       "Tag: py3-none-any\n"}
    record = [f"{path},sha256={_digest(text)},{len(text.encode())}" for path, text in files.items()]
    files[f"{dist}/RECORD"] = "\n".join([*record, f"{dist}/RECORD,,"]) + "\n"
    path = Path(directory) / f"{name}-{version}-py3-none-any.whl"
    with zipfile.ZipFile(path, "w") as zf:
        for file, text in files.items():
            zf.writestr(file, text)
    return path


def _digest(text: str) -> str:
    return base64.urlsafe_b64encode(hashlib.sha256(text.encode()).digest()).rstrip(b"=").decode()
