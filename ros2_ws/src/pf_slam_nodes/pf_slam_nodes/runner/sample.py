"""What `pf-slam run` inspects of a bag before it starts, read in one pass (bag inspection, part 0).

The inspection needs the first scans and the odometry among them (header stamps, the scan's
frame and range limits: runner/inputs.inspect_stamps), every /tf_static transform and the first
/tf messages (the lidar's mount and the robot's base frame: runner/mount.lidar_mount). One
pass over those topics collects them all and stops as soon as each is complete: /tf_static's
message count is known from the bag's metadata, so a bag whose static transforms come first (as
recorders write them) is read only as far as its first `max_scans` scans.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..io.bag import BagReadError, read_bag

#: /tf messages looked at for the robot's base frame (the child of odom)
TF_MESSAGES = 200


@dataclass
class BagSample:
    """The raw messages the inspection looks at: topic -> [(msgtype, record_ns, CDR bytes)].

    ``error``: the damage met during the pass (what precedes it is held); ``scans_wanted``: the
    scan count it read up to (fewer when the bag has fewer)."""

    path: str
    scan_topic: str
    odom_topic: str | None
    scans_wanted: int
    messages: dict[str, list[tuple[str, int, bytes]]] = field(default_factory=dict)
    error: BagReadError | None = None

    def of(self, topic: str) -> list[tuple[str, int, bytes]]:
        return self.messages.get(topic, [])


def sample_bag(bag: str, info: dict, inputs: dict[str, str], max_scans: int = 200) -> BagSample:
    """Read, in one pass, the first `max_scans` scans and the odometry until the last of them,
    all of /tf_static and the first TF_MESSAGES of /tf (each topic only if the bag has it)."""
    topics = info["topics"]
    scan = inputs["scan"]
    odom = inputs.get("odom") or inputs.get("encoders")
    s = BagSample(str(bag), scan, odom, max_scans)
    limits: dict[str, int | None] = {scan: max_scans}
    if odom:
        limits[odom] = None  # until the scans are complete
    if "/tf_static" in topics:
        limits["/tf_static"] = topics["/tf_static"][1]
    if "/tf" in topics:
        limits["/tf"] = TF_MESSAGES + 1
    for t in limits:
        s.messages[t] = []
    done = {t for t, n in limits.items() if n is not None and n <= 0}

    def complete(t: str) -> bool:
        if t == odom:
            return len(s.messages[scan]) >= max_scans
        return limits[t] is not None and len(s.messages[t]) >= limits[t]

    try:
        for t, msgtype, rec, raw in read_bag(bag, topics=[t for t in limits if t in topics or t == scan]):
            if t in done:
                continue
            s.messages[t].append((msgtype, rec, raw))
            for u in limits:
                if u not in done and complete(u):
                    done.add(u)
            if len(done) == len(limits):
                break
    except BagReadError as e:  # damaged mid-file: the consumers decide from what precedes it
        s.error = e
    return s
