"""Build a plant's devices from its field config: the SCS client its ``plant.protocol`` names
(Modbus TCP through a register map, or OPC UA through a node map) and each target's camera of
the ``kind`` its config gives (HTTP snapshot, stream, GenICam).

Only the composition roots (``app/``, ``commands/``) call these; the campaign core is handed the
objects and sees only :mod:`helicalib.devices.protocols`.
"""

from __future__ import annotations

from pathlib import Path

from helicalib.errors import ConfigError


def plant_from_config(cfg, *, armed: bool = False, register_map: str | Path | None = None, **kw):
    """The SCS client of ``cfg.plant``: a :class:`~helicalib.devices.modbus.ModbusPlant` speaking
    the plant's register map (``register_map`` overrides ``plant.register_map``: a YAML file or a
    shipped map's name), or a :class:`~helicalib.devices.opcua.OpcUaPlant`. Writes need ``armed``."""
    protocol = cfg.plant.protocol
    if protocol == "modbus":
        from helicalib.devices.modbus import ModbusPlant

        return ModbusPlant.from_config(cfg, armed=armed, register_map=register_map, **kw)
    if register_map is not None:
        raise ConfigError(f"--register-map {register_map}: the plant of {cfg.source} speaks OPC UA "
                          "(plant.protocol: opcua); its quantities are in plant.opcua.node_map")
    from helicalib.devices.opcua import OpcUaPlant

    return OpcUaPlant.from_config(cfg, armed=armed, **kw)


def cameras_from_config(cfg, timeout_s: float = 5.0, retries: int = 2, *, clock=None) -> dict:
    """One camera per target (the first camera configured for it), by target id, of the kind its
    config gives. ``clock`` (plant time) stamps the frames of cameras that do not carry a capture
    time of their own (stream and GenICam cameras)."""
    out: dict = {}
    for cam in cfg.cameras:
        if cam.target in out:
            continue
        size = cam.resolution_px if "resolution_px" in cam.model_fields_set else None
        if cam.kind == "http":
            from helicalib.devices.camera_http import HttpCamera

            out[cam.target] = HttpCamera(cam.url, timeout_s=timeout_s, retries=retries, expected_size_px=size)
        elif cam.kind == "stream":
            from helicalib.devices.camera_stream import StreamCamera

            out[cam.target] = StreamCamera.from_config(cam, clock=clock, timeout_s=timeout_s, expected_size_px=size)
        else:
            from helicalib.devices.camera_genicam import GenICamCamera

            out[cam.target] = GenICamCamera.from_config(cam, cfg, clock=clock, timeout_s=timeout_s,
                                                        expected_size_px=size)
    return out
