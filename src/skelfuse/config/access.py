"""Who may do what on a rig's zenoh network: identities, certificate names and the router's access control.

Every process of a secured rig holds a certificate signed by the rig's CA (``skelfuse certs``). Its
*identity* names the certificate and the role:

=====================  ==========================================================================
``router``             the zenoh router every other process connects to (``skelfuse router``)
``fusion``             the fusion node: publishes fused frames and its status, answers calibration
``capture-<host>``     a capture PC: publishes its own sensors' skeletons, statuses and camera tokens
``app-<name>``         anything else (viewers, recorders, game engines): subscribes and queries only
=====================  ==========================================================================

The certificate's common name is ``<identity>.<rig>.skelfuse`` (:func:`common_name`). The router enforces
:func:`access_control` (zenoh's ``access_control`` block, generated from the rig): default deny; every
certified process may subscribe, query and receive under ``skelfuse/<rig>/**``; a capture PC may publish
only its own sensors' keys; only the fusion node may publish fused frames, its status and the calibration.
A process without a certificate from the rig's CA cannot even connect (mutual TLS).
"""

from __future__ import annotations

from typing import Any

from skelfuse.config.model import RigConfig
from skelfuse.wire import keys

ROUTER = "router"
FUSION = "fusion"
CAPTURE_PREFIX = "capture-"
APP_PREFIX = "app-"


def capture_identity(host: str) -> str:
    """The identity of a capture PC."""
    return f"{CAPTURE_PREFIX}{keys.validate_name(host, 'capture host')}"


def app_identity(name: str) -> str:
    """The identity of an app (subscriber only)."""
    return f"{APP_PREFIX}{keys.validate_name(name, 'app')}"


def common_name(rig: str, identity: str) -> str:
    """The certificate common name of ``identity`` in ``rig``."""
    return f"{identity}.{rig}.skelfuse"


def capture_hosts(cfg: RigConfig) -> dict[str, tuple[str, ...]]:
    """Capture PC name -> the ids of the sensors it runs, in config order."""
    hosts: dict[str, list[str]] = {}
    for sensor in cfg.sensors:
        hosts.setdefault(sensor.capture_host, []).append(sensor.id)
    return {host: tuple(ids) for host, ids in hosts.items()}


def fusion_node_name(cfg: RigConfig) -> str:
    return cfg.node.name or "fusion"


def access_control(cfg: RigConfig) -> dict[str, Any]:
    """zenoh's ``access_control`` block for the rig's router (see the module docstring)."""
    rig = cfg.name
    rules = _shared_rules(f"skelfuse/{rig}/**")
    # No condition: every instance that connected at all, i.e. (mutual TLS) holds a certificate of the rig's CA.
    subjects: list[dict[str, Any]] = [{"id": "rig"}]
    policies: list[dict[str, Any]] = [{"rules": ["everyone-receives", "router-delivers"], "subjects": ["rig"]}]

    def allow(identity: str, publish: list[str], tokens: list[str], queryables: tuple[str, ...] = ()) -> None:
        subjects.append({"id": identity, "cert_common_names": [common_name(rig, identity)]})
        own = _identity_rules(identity, publish, tokens, queryables)
        rules.extend(own)
        policies.append({"rules": [rule["id"] for rule in own], "subjects": [identity]})

    node = fusion_node_name(cfg)
    allow(
        FUSION,
        [keys.fused_skeletons(rig), keys.status(rig, node)],
        [keys.alive(rig, node)],
        (keys.calibration(rig),),
    )
    for host, sensor_ids in capture_hosts(cfg).items():
        allow(
            capture_identity(host),
            [keys.sensor_skeletons(rig, sid) for sid in sensor_ids]
            + [keys.status(rig, f"capture-{sid}") for sid in sensor_ids],
            [keys.alive(rig, f"capture-{sid}") for sid in sensor_ids]
            + [keys.alive(rig, f"camera-{sid}") for sid in sensor_ids],
        )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def _shared_rules(everything: str) -> list[dict[str, Any]]:
    """The rules of every member of the rig: subscribe and query anything of the rig; the router delivers."""
    return [
        {
            "id": "everyone-receives",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query", "query"],
            "key_exprs": [everything],
        },
        {
            # What the router forwards to the clients that subscribed or queried (every message was checked
            # on its way in).
            "id": "router-delivers",
            "permission": "allow",
            "flows": ["egress"],
            "messages": [
                "put",
                "delete",
                "query",
                "reply",
                "liveliness_token",
                "liveliness_query",
                "declare_subscriber",
                "declare_queryable",
                "declare_liveliness_subscriber",
            ],
            "key_exprs": [everything],
        },
    ]


def _identity_rules(
    identity: str, publish: list[str], tokens: list[str], queryables: tuple[str, ...]
) -> list[dict[str, Any]]:
    """What one identity may do beyond receiving: publish its keys, hold its tokens, answer its queryables."""
    own = [
        {
            "id": f"{identity}-publishes",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["put"],
            "key_exprs": publish,
        },
        {
            "id": f"{identity}-tokens",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["liveliness_token"],
            "key_exprs": tokens,
        },
    ]
    if queryables:
        own.append(
            {
                "id": f"{identity}-answers",
                "permission": "allow",
                "flows": ["ingress"],
                "messages": ["declare_queryable", "reply"],
                "key_exprs": list(queryables),
            }
        )
    return own


def rig_identities(cfg: RigConfig, apps: tuple[str, ...] = ()) -> list[str]:
    """Every identity a secured rig needs a certificate for: router, fusion node, capture PCs, the apps."""
    return [ROUTER, FUSION, *(capture_identity(h) for h in capture_hosts(cfg)), *(app_identity(a) for a in apps)]
