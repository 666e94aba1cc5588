"""The OPC UA client's secured path against a real asyncua server on loopback.

Certificates are self-signed, made in tmp_path for the test (asyncua's ``crypto.cert_gen``); the
password comes from an environment variable, as ``plant.opcua.password_env`` asks. The client is
built from a field config with ``plant.protocol: opcua``, as a crew's run builds it.
"""

from __future__ import annotations

import ipaddress

import pytest
import yaml
from asyncua.crypto import cert_gen
from cryptography import x509
from cryptography.hazmat.primitives.serialization import Encoding
from cryptography.x509.oid import ExtendedKeyUsageOID

from helicalib.config import load_field_config
from helicalib.devices.connect import plant_from_config
from helicalib.devices.opcua import OpcUaPlant
from helicalib.devices.protocols import PlantUnreachableError
from helicalib.devices.registers import HeliostatState
from helicalib.errors import ConfigError, PlantError
from helicalib.geometry.sun import to_unix_seconds
from helicalib.sim.clock import RateClock
from helicalib.sim.opcua_server import OpcUaPlantService, ServerSecurity
from helicalib.sim.plant import SimulatedPlant

START = float(to_unix_seconds("2026-03-20T05:00:00Z"))
PASSWORD_ENV = "HELICALIB_TEST_OPCUA_PASSWORD"


def _certificate(folder, name: str, uri: str):
    """A self-signed application certificate and its key (PEM files in ``folder``)."""
    key = cert_gen.generate_private_key()
    cert = cert_gen.generate_self_signed_app_certificate(
        key, f"helicalib test {name}", {}, [x509.UniformResourceIdentifier(uri), x509.DNSName("localhost"),
                                           x509.IPAddress(ipaddress.ip_address("127.0.0.1"))],
        [ExtendedKeyUsageOID.CLIENT_AUTH, ExtendedKeyUsageOID.SERVER_AUTH])
    cert_path, key_path = folder / f"{name}.pem", folder / f"{name}-key.pem"
    cert_path.write_bytes(cert.public_bytes(Encoding.PEM))
    key_path.write_bytes(cert_gen.dump_private_key_as_pem(key))
    return cert_path, key_path


@pytest.fixture(scope="module")
def secured(demo_field_path, tmp_path_factory):
    folder = tmp_path_factory.mktemp("opcua-secure")
    server_cert, server_key = _certificate(folder, "server", "urn:helicalib:simulated-plant")
    client_cert, client_key = _certificate(folder, "client", "urn:helicalib:client")
    cfg = load_field_config(demo_field_path)
    plant = SimulatedPlant(cfg, start_s=START)
    security = ServerSecurity(server_cert, server_key, users={"crew": "s3cret-field"})
    svc = OpcUaPlantService(plant, RateClock(START, 1.0, lambda: 0.0), security=security).start()
    yield folder, svc, plant, client_cert, client_key
    svc.stop()


def _field(demo_field_path, folder, opcua: dict, name="field.yaml"):
    data = yaml.safe_load(demo_field_path.read_text())
    data["plant"] = {"protocol": "opcua", "clock": "plant", "opcua": opcua}
    data["storage"] = {"database": "sqlite:///c.db", "images_dir": "img"}
    path = folder / name
    path.write_text(yaml.safe_dump(data))
    return load_field_config(path)


def _opcua(svc, **kw):
    return {"endpoint": svc.endpoint, "node_map": "opcua-default", "security_policy": "Basic256Sha256",
            "security_mode": "SignAndEncrypt", "certificate": "client.pem", "private_key": "client-key.pem",
            "username": "crew", "password_env": PASSWORD_ENV, "timeout_s": 3.0, **kw}


def test_signed_and_encrypted_with_user_and_password_from_the_environment(secured, demo_field_path, monkeypatch):
    folder, svc, plant, *_ = secured
    monkeypatch.setenv(PASSWORD_ENV, "s3cret-field")
    cfg = _field(demo_field_path, folder, _opcua(svc))
    with plant_from_config(cfg, armed=True) as op:
        assert isinstance(op, OpcUaPlant)
        assert op.heliostat_count() == len(cfg.heliostats)
        assert op.status(4).state == HeliostatState(int(plant.state[4]))
        seq = op.stow(4)
        assert op.status(4).sequence_done == seq and int(plant.sequence_done[4]) == seq
    assert ("Stow", ("H0005", seq)) in svc.calls


def test_a_wrong_password_is_a_refusal_not_an_unreachable_plant(secured, demo_field_path, monkeypatch):
    folder, svc, *_ = secured
    monkeypatch.setenv(PASSWORD_ENV, "guess")
    cfg = _field(demo_field_path, folder, _opcua(svc))
    with plant_from_config(cfg) as op:
        with pytest.raises(PlantError) as err:
            op.heliostat_count()
    assert not isinstance(err.value, PlantUnreachableError)
    assert "\n" not in str(err.value) and svc.endpoint in str(err.value) and "refused" in str(err.value), err.value


def test_a_password_variable_that_is_not_set_is_a_config_error(secured, demo_field_path, monkeypatch):
    folder, svc, *_ = secured
    monkeypatch.delenv(PASSWORD_ENV, raising=False)
    cfg = _field(demo_field_path, folder, _opcua(svc))
    with pytest.raises(ConfigError, match=f"plant.opcua.password_env: the environment variable {PASSWORD_ENV} is not set"):
        plant_from_config(cfg)


def test_a_policy_without_the_clients_certificate_is_a_config_error(secured, demo_field_path):
    folder, svc, *_ = secured
    cfg = _field(demo_field_path, folder, _opcua(svc, certificate=None, private_key=None, password_env=None))
    with pytest.raises(ConfigError, match="security_policy Basic256Sha256 needs certificate and private_key"):
        plant_from_config(cfg)


def test_a_port_in_use_is_a_one_line_config_error(secured, demo_field_path):
    _folder, svc, plant, *_ = secured
    with pytest.raises(ConfigError, match=f"^OPC UA port {svc.port} on 127.0.0.1 is in use$"):
        OpcUaPlantService(plant, RateClock(START, 1.0, lambda: 0.0), port=svc.port).start()
