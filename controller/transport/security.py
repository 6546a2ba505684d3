"""The secure configuration of a Zenoh session: TLS, mutual authentication, access control by role.

A site's parties each hold a certificate issued by the site CA (``valvectl
certs DIR``) whose common name is their role:

========== ============================================ ==================================================
role       puts                                         subscribes
========== ============================================ ==================================================
controller ``cmd/duty``, ``ctrl/*`` but ``ctrl/mode``    ``meas/*``, ``ref/flow``, ``ctrl/mode``
valve      ``meas/*``                                   ``cmd/duty``
stack      ``ref/flow``, ``ctrl/mode``                   ``ctrl/*``, ``meas/*``
monitor    nothing                                      ``ctrl/*`` (read only)
========== ============================================ ==================================================

(keys under ``vent/valve/{id}``; every role may hold the liveliness token
``alive/{its role}`` and watch ``alive/*``; ``identify`` runs as the
controller: it commands the valve.)

:func:`secure` turns a session configuration into the secure one for a role:

* links are TLS only (``transport/link/protocols = ["tls"]``; ``tcp/``
  locators become ``tls/``), with the role's certificate and key on both
  the listening and the connecting side, and the site CA as the only root;
* mutual TLS: a peer without a certificate of the site CA cannot open a link
  (the handshake fails before any message);
* access control (``default_permission: deny``), enforced by every party on
  its own ingress: a put or a subscription is accepted from a peer only if
  the common name of its verified certificate is a role allowed that key;
  and on its egress: data goes to a peer only on the keys its role subscribes.
  A ``stack`` certificate cannot put ``meas/flow``, nor subscribe
  ``cmd/duty``; a ``monitor`` certificate cannot put anything.

Zenoh ids are not authenticated, certificate common names are: the access
control names roles, never ids. Every party carries the whole site policy,
so any party may listen or connect.
"""
from __future__ import annotations

import json
import os

#: The roles of a site, the common names of their certificates.
ROLES = ("controller", "valve", "stack", "monitor")

#: Keys (under ``vent/valve/{id}/``) each role may put.
PUTS = {
    "controller": ("cmd/duty", "ctrl/*"),  # but ctrl/mode: :data:`DENIED`
    "valve": ("meas/*",),
    "stack": ("ref/flow", "ctrl/mode"),
    "monitor": (),
}
#: Keys a role may not put although :data:`PUTS` matches them (an explicit deny wins over an allow).
DENIED = {"controller": ("ctrl/mode",)}
#: Keys each role may subscribe (monitor: read only).
SUBSCRIBES = {
    "controller": ("meas/*", "ref/flow", "ctrl/mode"),
    "valve": ("cmd/duty",),
    "stack": ("ctrl/*", "meas/*"),
    "monitor": ("ctrl/*",),
}
#: Liveliness: each role holds its own token, any role may watch the others'.
LIVELINESS_WATCH = "alive/*"


def role_files(certs_dir: str, role: str) -> dict[str, str]:
    """Paths of the site CA and the role's certificate and key (``DIR/ca.pem``, ``DIR/ROLE.pem``, ``DIR/ROLE.key``)."""
    return {"ca": os.path.join(certs_dir, "ca.pem"), "cert": os.path.join(certs_dir, f"{role}.pem"),
            "key": os.path.join(certs_dir, f"{role}.key")}


def check_files(certs_dir: str, role: str) -> dict[str, str]:
    """The role's files, each present and readable; ``InputError`` naming the first missing one."""
    from models.recording import InputError

    if role not in ROLES:
        raise InputError(f"--certs: no role {role!r} (roles: {', '.join(ROLES)})")
    files = role_files(certs_dir, role)
    for path in files.values():
        if not os.path.isfile(path):
            raise InputError(f"--certs {certs_dir}: {path}: no such file (make one with `valvectl certs {certs_dir}`)")
        if not os.access(path, os.R_OK):
            raise InputError(f"--certs {certs_dir}: {path}: not readable")
    return files


def tls_locator(ep: str) -> str:
    """``tcp/HOST:PORT`` as ``tls/HOST:PORT``; a ``tls/`` locator unchanged; anything else is bad input."""
    from models.recording import InputError

    if ep.startswith("tls/"):
        return ep
    if ep.startswith("tcp/"):
        return "tls/" + ep[4:]
    raise InputError(f"--certs: endpoint {ep!r}: a secure deployment links over tls/ (or tcp/, made tls/)")


def access_control(valve_id: str) -> dict:
    """The site's access control (Zenoh ``access_control``): one policy per role, deny by default."""
    k = f"vent/valve/{valve_id}"
    rules, subjects, policies = [], [], []
    for role in ROLES:
        mine = []
        if PUTS[role]:
            mine.append({"id": f"{role}-put", "permission": "allow", "flows": ["ingress"], "messages": ["put"],
                         "key_exprs": [f"{k}/{x}" for x in PUTS[role]]})
        if role in DENIED:
            mine.append({"id": f"{role}-deny", "permission": "deny", "flows": ["ingress"], "messages": ["put"],
                         "key_exprs": [f"{k}/{x}" for x in DENIED[role]]})
        mine.append({"id": f"{role}-sub", "permission": "allow", "flows": ["ingress"],
                     "messages": ["declare_subscriber"], "key_exprs": [f"{k}/{x}" for x in SUBSCRIBES[role]]})
        mine.append({"id": f"{role}-token", "permission": "allow", "flows": ["ingress"],
                     "messages": ["liveliness_token"], "key_exprs": [f"{k}/alive/{role}"]})
        mine.append({"id": f"{role}-watch", "permission": "allow", "flows": ["ingress"],
                     "messages": ["declare_liveliness_subscriber", "liveliness_query"],
                     "key_exprs": [f"{k}/{LIVELINESS_WATCH}"]})
        # Egress: data goes to a role only on the keys it subscribes; our own declarations go to any role.
        mine.append({"id": f"{role}-out", "permission": "allow", "flows": ["egress"], "messages": ["put"],
                     "key_exprs": [f"{k}/{x}" for x in SUBSCRIBES[role]]})
        mine.append({"id": f"{role}-decl-out", "permission": "allow", "flows": ["egress"],
                     "messages": ["declare_subscriber", "liveliness_token", "declare_liveliness_subscriber",
                                  "liveliness_query"], "key_exprs": [f"{k}/**"]})
        rules += mine
        subjects.append({"id": role, "cert_common_names": [role]})
        policies.append({"id": role, "rules": [r["id"] for r in mine], "subjects": [role]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def secure(conf, certs_dir: str, role: str, valve_id: str = "insp") -> None:
    """Make ``conf`` (a ``zenoh.Config`` with its endpoints set) the secure configuration of ``role``.

    The one place that builds it: ``run`` (role ``controller``), ``valve-node``
    (``valve``), ``identify`` (``controller``) and ``monitor`` (``monitor``)
    call it through :func:`controller.transport.zenoh.open_session` with
    ``certs=DIR``. Endpoints already inserted are turned into ``tls/``
    locators; the role's files are checked first.

    Parameters
    ----------
    conf : zenoh.Config
        Modified in place.
    certs_dir : str
        Folder made by ``valvectl certs``: ``ca.pem``, ``ROLE.pem``, ``ROLE.key``.
    role : str
        One of :data:`ROLES`: the common name of the certificate used.
    valve_id : str
        The key prefix ``vent/valve/{id}`` the access control covers.

    Raises
    ------
    models.recording.InputError
        A missing file, an unknown role, or a non-TCP/TLS endpoint.
    """
    files = check_files(certs_dir, role)
    for side in ("listen", "connect"):
        eps = json.loads(conf.get_json(f"{side}/endpoints") or "[]")
        if isinstance(eps, dict):  # per-mode endpoints ({"peer": [...], ...})
            eps = {m: [tls_locator(e) for e in v] for m, v in eps.items()}
        else:
            eps = [tls_locator(e) for e in eps]
        conf.insert_json5(f"{side}/endpoints", json.dumps(eps))
    tls = {
        "root_ca_certificate": files["ca"],
        "listen_private_key": files["key"],
        "listen_certificate": files["cert"],
        "connect_private_key": files["key"],
        "connect_certificate": files["cert"],
        "enable_mtls": True,
        "verify_name_on_connect": True,
    }
    for name, value in tls.items():
        conf.insert_json5(f"transport/link/tls/{name}", json.dumps(value))
    conf.insert_json5("transport/link/protocols", '["tls"]')
    conf.insert_json5("access_control", json.dumps(access_control(valve_id)))
