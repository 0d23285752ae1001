"""metro measure --opcua: a real asyncua client subscribed to the server that ``metro measure -
--follow --opcua`` starts (its own process, a free port on 127.0.0.1) receives one result per hole,
equal to the hole's answer on stdout and to the batch run's ``--out`` table, and the alarm of a
knocked sensor (the forward simulator's ``--shift``); bad endpoints exit 2 at start; a client that
stops reading is dropped with a warning while measuring goes on. No mocks."""

import asyncio
import csv
import json
import os
import signal
import socket
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.data import data_path
from metrology.jobs.measure_follow import UNIT_LINES
from tests.plant.opcua_client import Metro, connect, free_port, subscribe

asyncua = pytest.importorskip("asyncua")
runner = CliRunner()
TABLE6 = data_path("measured", "nominal.toml")
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.fixture(scope="module")
def knocked(tmp_path_factory):
    """1150 holes of the forward simulator, sensor L3 knocked by 0.03 mm at hole 1060."""
    tmp = tmp_path_factory.mktemp("knock")
    log = tmp / "knock.csv"
    r = runner.invoke(app, ["simulate-log", "--out", str(log), "--holes", "1150", "--panel", "flat", "--seed", "3",
                            "--layout", str(TABLE6), "--true-layout", str(TABLE6), "--spin-deg", "1",
                            "--shift", "L3:0.03@1060"])
    assert r.exit_code == 0, r.output
    return log


async def _follow_with_client(log, tmp):
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    metro = Metro(["measure", "-", "--layout", str(TABLE6), "--follow", "--opcua", url], tmp, ROOT)
    try:
        client = await connect(url, proc=metro.proc)
        _, col = await subscribe(client)
        metro.feed(log.read_text())
        rc, out, err = await asyncio.get_running_loop().run_in_executor(None, metro.finish)
        # what the client's loop had not handled yet when metro ended: wait for the count stdout gives (a
        # lost result still fails below, after the wait), not for a pause, which a loaded machine makes
        expected = sum(1 for x in out.splitlines() if '"hole_id"' in x and '"line"' in x)
        end = asyncio.get_running_loop().time() + 120.0
        while len(col.results) < expected and asyncio.get_running_loop().time() < end:
            await asyncio.sleep(0.2)
        return rc, out, err, col
    finally:
        metro.kill()


def test_a_subscribed_client_gets_every_hole_and_the_knock_alarm(knocked, tmp_path):
    rc, out, err, col = asyncio.run(_follow_with_client(knocked, tmp_path))
    assert rc in (0, 1), err
    lines = [json.loads(x) for x in out.splitlines()]
    holes = [x for x in lines if "hole_id" in x and "line" in x]
    assert len(holes) == 1150
    got = col.results
    assert len(got) == 1150, "a result lost"
    assert [r["Sequence"] for r in got] == list(range(1, 1151)), "results reordered"
    for r, h in zip(got, holes):
        after = h["angle_after_deg"]
        use_after = after is not None and after == after
        assert r["CharacteristicIdentifier"] == h["hole_id"] and r["Line"] == h["line"]
        assert r["ResultValue"] == (after if use_after else h["angle_deg"])
        assert r["U95"] == (h["U95_after_deg"] if use_after else h["U95_angle_deg"])
        assert r["Status"] == h["status"] and r["UpperToleranceLimit"] == 0.5 and r["Nominal"] == 0.0
        assert r["ResultEvaluation"] == {"conforms": 1, "fails": 2, "undecided": 3, "not_measured": 0}[h["status"]]
        assert r["IsValid"] == (h["status"] != "not_measured")
        assert r["Cell"] == "C1" and r["SourceName"] == "C1"
    # the knocked sensor's alarm, as an event with its severity, right after its hole's result
    raised = [a for a in col.alarms if a["Alarm"] == "raised"]
    assert raised and raised[0]["Severity"] == 700 and raised[0]["Cell"] == "C1"
    at = int(raised[0]["HoleId"].split("-")[1])
    assert 1060 <= at <= 1100
    # the same values as the batch run's --out table (the follow test's tolerance: one row vs batches)
    out_csv = tmp_path / "out.csv"
    r = runner.invoke(app, ["measure", str(knocked), "--layout", str(TABLE6), "--out", str(out_csv), "--json"])
    assert r.exit_code in (0, 1), r.output
    with open(out_csv, newline="") as fh:
        table = list(csv.DictReader(fh))
    assert [t["hole_id"] for t in table] == [g["CharacteristicIdentifier"] for g in got]
    judged = [float(t["angle_after_deg"]) if t["angle_after_deg"] not in ("", "nan") else float(t["angle_deg"])
              for t in table]
    np.testing.assert_allclose([g["ResultValue"] for g in got], judged, rtol=1e-9)


async def _read_space(url, proc):
    from asyncua import ua

    client = await connect(url, proc=proc)
    try:
        ns = await client.get_namespace_index("urn:metro:plant")
        gms = await client.get_namespace_index("http://opcfoundation.org/UA/GMS/")
        # the event types where docs/plant.md says they are
        assert (await client.get_node(ua.NodeId(1, ns)).read_browse_name()).Name == "HoleResultReadyEventType"
        assert (await client.get_node(ua.NodeId(2, ns)).read_browse_name()).Name == "DriftAlarmEventType"
        sha = await client.get_node(ua.NodeId("cell/C1/Calibration", ns)).get_child(f"{ns}:Sha256")
        value = await client.get_node(ua.NodeId("cell/C1/LastResult", ns)).get_child(f"{gms}:ResultValue")
        denied = None
        try:
            await value.write_value(ua.DataValue(ua.Variant(1.0, ua.VariantType.Double)))
        except ua.UaStatusCodeError as exc:
            denied = type(exc).__name__
        return await sha.read_value(), await value.read_value(), denied
    finally:
        await client.disconnect()


def test_the_calibration_is_readable_and_nothing_is_writable(knocked, tmp_path):
    """The cell's head after a few holes: its calibration's SHA-256 and last result read; an
    anonymous write is refused."""
    import hashlib

    url = f"opc.tcp://127.0.0.1:{free_port()}"
    metro = Metro(["measure", "-", "--layout", str(TABLE6), "--follow", "--opcua", url], tmp_path, ROOT)
    proc = metro.proc
    try:
        head = "\n".join(knocked.read_text().splitlines()[:1 + UNIT_LINES]) + "\n"
        proc.stdin.write(head)
        proc.stdin.flush()
        for _ in range(UNIT_LINES):  # the held lines' answers on stdout: the cell's node exists
            assert proc.stdout.readline()
        sha, value, denied = asyncio.run(_read_space(url, proc))
        proc.stdin.close()
        rc, _, err = metro.finish()
        assert rc in (0, 1), err
    finally:
        metro.kill()
    assert sha == hashlib.sha256(TABLE6.read_bytes()).hexdigest()
    assert isinstance(value, float) and value > 0
    assert denied in ("BadUserAccessDenied", "BadNotWritable")


def test_port_in_use_exits_2_at_start(knocked):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        r = runner.invoke(app, ["measure", str(knocked), "--layout", str(TABLE6), "--follow", "--opcua",
                                f"opc.tcp://127.0.0.1:{port}"])
    assert r.exit_code == 2
    assert r.stderr.count("\n") == 1 and "cannot listen" in r.stderr and "in use" in r.stderr
    assert r.stdout == ""  # nothing measured


def test_a_host_that_is_not_loopback_needs_certificate_and_users(knocked, tmp_path):
    from metrology.plant.server import parse_endpoint

    assert parse_endpoint("opc.tcp://:4840") == ("127.0.0.1", 4840, True)  # no host: loopback
    assert parse_endpoint("opc.tcp://localhost:4840")[2] and not parse_endpoint("opc.tcp://0.0.0.0:4840")[2]
    r = runner.invoke(app, ["measure", str(knocked), "--layout", str(TABLE6), "--follow", "--opcua",
                            f"opc.tcp://0.0.0.0:{free_port()}"])
    assert r.exit_code == 2 and "not loopback" in r.stderr and r.stdout == ""
    r = runner.invoke(app, ["measure", str(knocked), "--layout", str(TABLE6), "--follow", "--opcua", "http://x:1"])
    assert r.exit_code == 2 and "opc.tcp://HOST:PORT" in r.stderr


def test_an_unreachable_interface_exits_2_at_start(knocked, tmp_path):
    """192.0.2.1 (TEST-NET-1) is on no interface of this machine: binding it fails, nothing is sent."""
    import hashlib

    from asyncua.crypto.cert_gen import dump_private_key_as_pem, generate_private_key, generate_self_signed_app_certificate
    from cryptography.hazmat.primitives.serialization import Encoding
    from cryptography.x509.oid import ExtendedKeyUsageOID

    key = generate_private_key()
    cert = generate_self_signed_app_certificate(key, "metro", {}, [], [ExtendedKeyUsageOID.SERVER_AUTH])
    (tmp_path / "key.pem").write_bytes(dump_private_key_as_pem(key))
    (tmp_path / "cert.pem").write_bytes(cert.public_bytes(Encoding.PEM))
    (tmp_path / "users").write_text(f"cell1:{hashlib.sha256(b'secret').hexdigest()}\n")
    r = runner.invoke(app, ["measure", str(knocked), "--layout", str(TABLE6), "--follow", "--opcua",
                            f"opc.tcp://192.0.2.1:{free_port()}", "--opcua-cert", str(tmp_path / "cert.pem"),
                            "--opcua-key", str(tmp_path / "key.pem"), "--opcua-users", str(tmp_path / "users")])
    assert r.exit_code == 2 and "cannot listen" in r.stderr and r.stderr.count("\n") == 1 and r.stdout == ""


STALLED = """
import asyncio, sys
sys.path.insert(0, {root!r})
from tests.plant.opcua_client import connect, subscribe
async def main():
    c = await connect({url!r})
    await subscribe(c)
    print("subscribed", flush=True)
    await asyncio.sleep(600)
asyncio.run(main())
"""


def test_a_client_that_stops_reading_is_dropped_and_measuring_goes_on(knocked, tmp_path):
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    metro = Metro(["measure", "-", "--layout", str(TABLE6), "--follow", "--opcua", url, "--opcua-queue", "300"],
                  tmp_path, ROOT)
    client = subprocess.Popen([sys.executable, "-c", STALLED.format(root=ROOT, url=url)], stdout=subprocess.PIPE,
                              text=True)
    try:
        assert client.stdout.readline().strip() == "subscribed"
        client.send_signal(signal.SIGSTOP)  # it neither reads nor asks for notifications any more
        metro.feed(knocked.read_text())
        rc, out, err = metro.finish()
    finally:
        client.send_signal(signal.SIGCONT)
        client.kill()
        client.wait()
        metro.kill()
    assert rc in (0, 1), err
    holes = [x for x in map(json.loads, out.splitlines()) if "hole_id" in x and "line" in x]
    assert len(holes) == 1150
    assert "a client is not reading" in err and "subscription" in err


async def _whole_log(log, out_csv, tmp):
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    metro = Metro(["measure", str(log), "--layout", str(TABLE6), "--out", str(out_csv), "--json", "--opcua", url,
                   "--opcua-wait-s", "300"], tmp, ROOT)
    try:
        client = await connect(url, proc=metro.proc)
        _, col = await subscribe(client)
        rc, out, err = await asyncio.get_running_loop().run_in_executor(None, metro.finish)
        return rc, err, col
    finally:
        metro.kill()


def test_a_whole_log_sends_every_hole_equal_to_the_out_table(knocked, tmp_path):
    """Without --follow: the server waits for the client (--opcua-wait-s), then every hole's result
    goes out as the log is measured, each value the --out table's own."""
    log = tmp_path / "head.csv"
    log.write_text("".join(knocked.read_text().splitlines(keepends=True)[:301]))
    out_csv = tmp_path / "out.csv"
    rc, err, col = asyncio.run(_whole_log(log, out_csv, tmp_path))
    assert rc in (0, 1), err
    with open(out_csv, newline="") as fh:
        table = list(csv.DictReader(fh))
    assert len(col.results) == len(table) == 300
    assert [r["Sequence"] for r in col.results] == list(range(1, 301))
    for r, t in zip(col.results, table):
        use_after = t["angle_after_deg"] not in ("", "nan")
        assert r["CharacteristicIdentifier"] == t["hole_id"] and r["Status"] == t["status"]
        assert r["ResultValue"] == float(t["angle_after_deg"] if use_after else t["angle_deg"])
        assert r["U95"] == float(t["U95_after_deg"] if use_after else t["U95_angle_deg"])


def _pem_pair(tmp, name, uri, usage):
    from asyncua.crypto.cert_gen import dump_private_key_as_pem, generate_private_key, generate_self_signed_app_certificate
    from cryptography import x509
    from cryptography.hazmat.primitives.serialization import Encoding

    key = generate_private_key()
    cert = generate_self_signed_app_certificate(key, name, {}, [x509.UniformResourceIdentifier(uri),
                                                                x509.DNSName("localhost")], [usage])
    (tmp / f"{name}.key.pem").write_bytes(dump_private_key_as_pem(key))
    (tmp / f"{name}.cert.pem").write_bytes(cert.public_bytes(Encoding.PEM))
    return tmp / f"{name}.cert.pem", tmp / f"{name}.key.pem"


async def _secure_session(url, proc, client_cert, client_key, user, password):
    """(anonymous refused?, the user's session reads the calibration's SHA-256)"""
    from asyncua import Client, ua

    anonymous = Client(url, timeout=30)
    try:
        await anonymous.connect()
        refused = False
        await anonymous.disconnect()
    except Exception:  # noqa: BLE001 - no endpoint without security, no anonymous token: refused
        refused = True
    c = Client(url, timeout=30)
    c.application_uri = "urn:metro:test-client"
    await c.set_security_string(f"Basic256Sha256,SignAndEncrypt,{client_cert},{client_key}")
    c.set_user(user)
    c.set_password(password)
    await c.connect()
    try:
        ns = await c.get_namespace_index("urn:metro:plant")
        sha = await (await c.get_node(ua.NodeId("cell/C1/Calibration", ns)).get_child(f"{ns}:Sha256")).read_value()
    finally:
        await c.disconnect()
    return refused, sha


def test_with_certificate_and_users_only_a_user_over_an_encrypted_channel_gets_in(knocked, tmp_path):
    import hashlib

    from cryptography.x509.oid import ExtendedKeyUsageOID

    cert, key = _pem_pair(tmp_path, "server", "urn:metro:measure", ExtendedKeyUsageOID.SERVER_AUTH)
    ccert, ckey = _pem_pair(tmp_path, "client", "urn:metro:test-client", ExtendedKeyUsageOID.CLIENT_AUTH)
    (tmp_path / "users").write_text(f"# cell controllers\ncell1:{hashlib.sha256(b'secret').hexdigest()}\n")
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    metro = Metro(["measure", "-", "--layout", str(TABLE6), "--follow", "--opcua", url, "--opcua-cert", str(cert),
                   "--opcua-key", str(key), "--opcua-users", str(tmp_path / "users")], tmp_path, ROOT)
    proc = metro.proc
    try:
        # the header and 5 holes: --follow answers once it has the lines its units check holds (UNIT_LINES)
        proc.stdin.write("".join(knocked.read_text().splitlines(keepends=True)[:1 + UNIT_LINES]))
        proc.stdin.flush()
        for _ in range(UNIT_LINES):
            assert proc.stdout.readline()
        refused, sha = asyncio.run(_secure_session(url, proc, ccert, ckey, "cell1", "secret"))
        proc.stdin.close()
        rc, _, err = metro.finish()
        assert rc in (0, 1), err
    finally:
        metro.kill()
    assert refused
    assert sha == hashlib.sha256(TABLE6.read_bytes()).hexdigest()
