"""An environment's fingerprint: what a run trained on, so that an edited spec (or model file) is noticed.

The sha256 of the spec as its model reads it (every field, defaults included, as JSON with sorted keys)
and, for an `mjcf` spec, of the bytes of its XML and of every file the XML loads: changing a reward weight,
the body, a mesh or an include changes it; moving the spec folder elsewhere does not."""

from __future__ import annotations

import hashlib
import json

from miktcli import limits
from miktcli.envs.mjcf import model_files
from miktcli.envs.spec import LATER_DEFAULTS, AnySpec, MjcfSpec


def spec_record(spec: AnySpec) -> dict:
    """The spec as its fields read (paths as written in the file, not where it lies now); a field added
    later is left out at its default, so a spec written before it existed keeps its fingerprint."""
    record = spec.model_dump(mode="json")
    later = LATER_DEFAULTS.get(type(spec), {})
    return {k: v for k, v in record.items() if k not in later or v != later[k]}


def spec_fingerprint(spec: AnySpec) -> str:
    digest = hashlib.sha256(json.dumps(spec_record(spec), sort_keys=True).encode())
    if isinstance(spec, MjcfSpec):
        xml = spec.xml_path()
        for path in [xml, *model_files(xml)]:
            digest.update(b"\0" + path.name.encode() + b"\0")
            digest.update(limits.read_file_bounded(path, str(path), limits.MAX_MODEL_FILE_BYTES))
    return digest.hexdigest()


def describe_change(env: str, recorded: str, now: str, what: str) -> str:
    return (f"environment '{env}' changed since {what} (spec and model files sha256 {recorded[:12]} then, "
            f"{now[:12]} now): it would be another body or reward")
