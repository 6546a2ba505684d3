"""``valvectl certs`` and the secure configuration (``--certs``): TLS, mutual authentication, access by role.

Deliveries are counted on receivers holding the site's own certificates: a
rogue with no certificate, one from another CA, or the wrong role delivers
0 of 200; the legitimate party 200 of 200. Then the real controller and
valve node run secured beside rogues, which never reach the loop.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

zenoh = pytest.importorskip("zenoh")
x509 = pytest.importorskip("cryptography.x509")

from controller.transport.security import PUTS, ROLES, SUBSCRIBES, access_control, secure  # noqa: E402
from tests.zenoh_helpers import ROOT, free_port, rows, valvectl, wait_for  # noqa: E402

P = "vent/valve/insp"
N = 200


@pytest.fixture(scope="module")
def sites(tmp_path_factory):
    """The site's certificates and a foreign CA's."""
    base = tmp_path_factory.mktemp("certs")
    for name in ("site", "other"):
        r = subprocess.run([sys.executable, "-m", "controller.cli", "certs", str(base / name)], cwd=ROOT,
                           capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
    return base / "site", base / "other"


def test_certs_writes_a_ca_and_one_certificate_per_role(sites):
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    site, other = sites
    ca = x509.load_pem_x509_certificate((site / "ca.pem").read_bytes())
    assert ca.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    for role in ROLES:
        cert = x509.load_pem_x509_certificate((site / f"{role}.pem").read_bytes())
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == role
        assert cert.issuer == ca.subject
        ca.public_key().verify(cert.signature, cert.tbs_certificate_bytes, ec.ECDSA(cert.signature_hash_algorithm))
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        assert "localhost" in san.get_values_for_type(x509.DNSName)
        assert [str(a) for a in san.get_values_for_type(x509.IPAddress)] == ["127.0.0.1"]
        assert os.stat(site / f"{role}.key").st_mode & 0o077 == 0  # keys readable by the owner only
    foreign = x509.load_pem_x509_certificate((other / "valve.pem").read_bytes())
    with pytest.raises(Exception):
        ca.public_key().verify(foreign.signature, foreign.tbs_certificate_bytes,
                               ec.ECDSA(foreign.signature_hash_algorithm))


@pytest.mark.parametrize("args, words", [
    (["certs", "{site}"], "exists"),
    (["certs", "{tmp}/new", "--host", "bad host"], "--host"),
    (["certs", "{tmp}/new2", "--days", "0"], "--days"),
    (["run", "--plant", "zenoh", "--certs", "{tmp}/none", "--duration", "1"], "no such file"),
    (["valve-node", "--certs", "{site}", "--connect", "udp/127.0.0.1:9", "--duration", "1"], "tls/"),
])
def test_bad_certs_input_is_one_line_exit_2(sites, tmp_path, args, words):
    args = [a.format(site=sites[0], tmp=tmp_path) for a in args]
    r = subprocess.run([sys.executable, "-m", "controller.cli", *args], cwd=ROOT, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], r.stderr
    assert not (tmp_path / "new").exists()


def test_access_control_names_each_role_and_denies_by_default():
    acl = access_control("insp")
    assert acl["enabled"] and acl["default_permission"] == "deny"
    assert {s["id"]: s["cert_common_names"] for s in acl["subjects"]} == {r: [r] for r in ROLES}
    allowed_puts = {}
    for pol in acl["policies"]:
        for rid in pol["rules"]:
            r = next(x for x in acl["rules"] if x["id"] == rid)
            if r["messages"] == ["put"] and r["flows"] == ["ingress"] and r["permission"] == "allow":
                allowed_puts[pol["subjects"][0]] = r["key_exprs"]
    assert allowed_puts == {r: [f"{P}/{k}" for k in PUTS[r]] for r in ROLES if PUTS[r]}
    assert "monitor" not in allowed_puts
    assert all(k.startswith("ctrl/") for k in SUBSCRIBES["monitor"])


# ---- deliveries between sessions over TLS ---------------------------------------------------------


def config(listen=(), connect=(), certs=None, role=None) -> zenoh.Config:
    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("listen/endpoints", json.dumps(list(listen)))
    c.insert_json5("connect/endpoints", json.dumps(list(connect)))
    c.insert_json5("connect/timeout_ms", "2000")
    c.insert_json5("connect/exit_on_failure", "false")
    if certs is not None:
        secure(c, str(certs), role)
    return c


def rogue_config(kind: str, ep: str, site, other) -> zenoh.Config:
    """A rogue connecting to ``ep`` (tls/...): no certificate, a foreign one, or the site's of a wrong role."""
    if kind == "plain tcp":
        return config(connect=["tcp/" + ep.split("/", 1)[1]])
    if kind.startswith("role "):
        return config(connect=[ep], certs=site, role=kind.split()[1])
    c = config(connect=[ep])
    c.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(str(site / "ca.pem")))  # trusts the site
    if kind == "foreign CA":  # but presents a certificate of another CA, with the right common name
        c.insert_json5("transport/link/tls/connect_certificate", json.dumps(str(other / "valve.pem")))
        c.insert_json5("transport/link/tls/connect_private_key", json.dumps(str(other / "valve.key")))
    return c


def count(sub) -> int:
    n = 0
    while sub.try_recv() is not None:
        n += 1
    return n


def put_all(session, key: str, matched: bool = False) -> None:
    """``N`` puts on ``key``; ``matched``: from when a subscription has reached ``session`` (no fixed wait)."""
    pub = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
    if matched:
        wait_for(lambda: pub.matching_status.matching, f"a subscription to {key} at the publisher")
    for k in range(N):
        pub.put(json.dumps({"t": 0.0, "seq": k, "value": 1.0}).encode())


#: (rogue, the key it puts, the receiving role). Wrong roles: the site's certificates used for keys
#: their role may not put.
ROGUES = [
    ("plain tcp", "meas/flow", "controller"),
    ("no certificate", "meas/flow", "controller"),
    ("foreign CA", "meas/flow", "controller"),
    ("role stack", "meas/flow", "controller"),
    ("role monitor", "ref/flow", "controller"),
    ("role valve", "ctrl/mode", "controller"),
    ("role stack", "cmd/duty", "valve"),
    ("role monitor", "cmd/duty", "valve"),
    ("no certificate", "cmd/duty", "valve"),
]
LEGIT = {"meas/flow": "valve", "ref/flow": "stack", "ctrl/mode": "stack", "cmd/duty": "controller"}


@pytest.mark.parametrize("rogue, key, receiver", ROGUES, ids=[f"{r}-{k}" for r, k, _ in ROGUES])
def test_rogues_deliver_nothing_and_the_legitimate_party_everything(sites, rogue, key, receiver):
    site, other = sites
    ep = f"tls/localhost:{free_port()}"
    with zenoh.open(config(listen=[ep], certs=site, role=receiver)) as rx:
        sub = rx.declare_subscriber(f"{P}/{key}", zenoh.handlers.RingChannel(10 * N))
        with zenoh.open(rogue_config(rogue, ep, site, other)) as bad:
            if rogue.startswith("role "):  # a verified link: the access control alone stops it
                wait_for(lambda: list(bad.info.peers_zid()), "the rogue's link")
            else:
                time.sleep(1.0)  # its connection attempts: refused by the TLS handshake
                assert list(bad.info.peers_zid()) == []
            put_all(bad, f"{P}/{key}")
            time.sleep(0.5)
        assert count(sub) == 0
        with zenoh.open(config(connect=[ep], certs=site, role=LEGIT[key])) as good:
            put_all(good, f"{P}/{key}", matched=True)  # once the subscription's declaration reached it
            got = [0]  # counted as they come: the test ends when all N are in, not after a fixed wait

            def all_in() -> bool:
                got[0] += count(sub)
                return got[0] >= N

            wait_for(all_in, "the legitimate samples")
        assert got[0] + count(sub) == N


def test_a_monitor_reads_status_but_not_commands(sites):
    """Subscriptions by role: a monitor certificate receives ctrl/status, never cmd/duty."""
    site, _ = sites
    ep = f"tls/localhost:{free_port()}"
    with zenoh.open(config(listen=[ep], certs=site, role="controller")) as ctl, \
            zenoh.open(config(connect=[ep], certs=site, role="monitor")) as mon:
        wait_for(lambda: list(mon.info.peers_zid()), "the monitor's link")
        status = mon.declare_subscriber(f"{P}/ctrl/status", zenoh.handlers.RingChannel(10 * N))
        cmd = mon.declare_subscriber(f"{P}/cmd/duty", zenoh.handlers.RingChannel(10 * N))
        time.sleep(0.5)
        put_all(ctl, f"{P}/cmd/duty")
        put_all(ctl, f"{P}/ctrl/status")
        wait_for(lambda: status.try_recv() is not None, "status at the monitor")
        time.sleep(0.5)
        assert count(cmd) == 0


# ---- the secured loop beside rogues (real processes) ---------------------------------------------


def test_secured_loop_runs_and_rogues_never_reach_it(sites, tmp_path):
    site, other = sites
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    rec, summ = tmp_path / "run.csv", tmp_path / "s.json"
    ctrl = valvectl("run", "--plant", "zenoh", "--reference", "zenoh", "--listen", ep, "--certs", str(site),
                    "--duration", "0", "--record", str(rec), "--json", str(summ))
    node = valvectl("valve-node", "--connect", ep, "--certs", str(site))
    procs = (ctrl, node)
    tls = f"tls/127.0.0.1:{port}"
    try:
        with zenoh.open(config(connect=[tls], certs=site, role="stack")) as stack:
            ref = stack.declare_publisher(f"{P}/ref/flow")
            k = 0

            def reference(seconds):
                nonlocal k
                t_end = time.monotonic() + seconds
                while time.monotonic() < t_end:
                    ref.put(json.dumps({"t": 0.0, "seq": k, "value": 40.0}).encode())
                    k += 1
                    time.sleep(0.01)

            wait_for(lambda: (reference(0.05), any(r[6] == "running" and float(r[1]) == 40.0
                                                   for r in rows(rec)[-50:]))[1], "the secured loop running", procs)
            kinds = ("plain tcp", "no certificate", "foreign CA", "role stack", "role monitor", "role valve")
            rogues = [zenoh.open(rogue_config(kind, tls, site, other)) for kind in kinds]
            try:
                reference(1.0)
                for kind, r in zip(kinds, rogues):
                    for key, v in (("meas/flow", 123.25), ("ref/flow", 77.75), ("cmd/duty", 100.0)):
                        if kind.startswith("role ") and key in LEGIT and LEGIT[key] == kind.split()[1]:
                            continue  # the role's own key: not a rogue put
                        pub = r.declare_publisher(f"{P}/{key}")
                        for j in range(N):
                            pub.put(json.dumps({"t": 0.0, "seq": 10 ** 9 + j, "value": v}).encode())
                reference(1.0)
            finally:
                for r in rogues:
                    r.close()
        for p in (ctrl, node):  # the controller first: it ends running, not stale
            p.send_signal(signal.SIGTERM)
            _, err = p.communicate(timeout=60)
            assert p.returncode == 0, err
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    table = rows(rec)
    assert not any(float(r[2]) == 123.25 or float(r[1]) == 77.75 for r in table)
    state = np.array([r[6] for r in table])
    assert state[-1] == "running"
    faults = {f["kind"] for f in json.loads(summ.read_text())["faults"]}
    assert not faults & {"bad_measurement", "spoofed_measurement", "bad_reference"}
