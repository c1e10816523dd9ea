"""The Fast DDS profile the node processes of one run get (config/fastdds_large_data.xml)."""

from __future__ import annotations

import xml.etree.ElementTree as ET

from pf_slam_nodes.runner.supervise import FASTDDS_PROFILE, fastdds_env

NS = {"f": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}


def test_node_processes_get_the_large_data_profile_unless_one_is_set():
    assert fastdds_env({"A": "1"}) == {"A": "1", "FASTRTPS_DEFAULT_PROFILES_FILE": str(FASTDDS_PROFILE)}
    for key in ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE"):
        assert fastdds_env({key: "/mine.xml"}) == {key: "/mine.xml"}  # the user's profile wins


def test_the_profile_holds_a_stereo_pair_in_shared_memory_and_keeps_udp():
    root = ET.parse(FASTDDS_PROFILE).getroot()
    kinds = {d.find("f:transport_id", NS).text: d for d in root.iterfind(".//f:transport_descriptor", NS)}
    shm = [d for d in kinds.values() if d.find("f:type", NS).text == "SHM"]
    assert len(shm) == 1 and int(shm[0].find("f:segment_size", NS).text) >= 2 * 1280 * 560 * 2
    assert any(d.find("f:type", NS).text == "UDPv4" for d in kinds.values())  # discovery, other hosts
    part = root.find(".//f:participant", NS)
    assert part.get("is_default_profile") == "true"
    used = [t.text for t in part.iterfind(".//f:userTransports/f:transport_id", NS)]
    assert sorted(used) == sorted(kinds)
