"""companion.mavlink.statustext: the companion's lines to the ground station, chunked as MAVLink 2 says, sent on
a real Link over UDP and joined again by a receiver that shares no code with the sender's framing."""

from __future__ import annotations

import pytest

from companion.mavlink.link import Link
from companion.mavlink.statustext import TEXT_BYTES, Reassembler, Severity, StatusTexts, chunks


def test_a_short_line_is_one_message_with_id_zero():
    assert chunks("plan accepted", 7) == [(b"plan accepted", 0, 0)]
    assert chunks("x" * TEXT_BYTES, 7) == [(b"x" * TEXT_BYTES, 0, 0)]


@pytest.mark.parametrize("n", [51, 99, 100, 149, 399])
def test_a_long_line_is_chunked_and_ends_unambiguously(n):
    text = "".join(chr(ord("a") + k % 26) for k in range(n))
    parts = chunks(text, 513)
    assert all(len(p) <= TEXT_BYTES and ident == 513 for p, ident, _ in parts)
    assert [seq for *_, seq in parts] == list(range(len(parts)))
    assert b"".join(p for p, *_ in parts) == text.encode()
    assert len(parts[-1][0]) < TEXT_BYTES  # the receiver sees a NUL in the last chunk
    with pytest.raises(ValueError):
        chunks(text, 0)  # id 0 means "the only chunk"


def test_a_very_long_line_is_cut_to_eight_chunks():
    parts = chunks("y" * 1000, 9)
    assert len(parts) == 8 and len(parts[-1][0]) == TEXT_BYTES - 1


def test_non_ascii_is_replaced_not_dropped():
    assert chunks("hold 5 s – intruder", 1)[0][0] == b"hold 5 s ? intruder"


@pytest.mark.asyncio
async def test_lines_reach_a_receiver_whole_over_udp(raw_peer):
    long = "replan 2 live: 18 items, 1446 m, clearance 24.5 m, intruder ICAO 4CA1FA passed 310 m away"
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}", source_component=195) as link:
        await raw_peer.recv_type("HEARTBEAT")
        out = StatusTexts(link)
        assert out.send("plan accepted", Severity.NOTICE)
        assert out.send(long, Severity.WARNING)
        joiner, lines, raw = Reassembler(), [], []
        while len(lines) < 2:
            for m in await raw_peer.recv(2.0):
                if m.get_type() == "STATUSTEXT":
                    raw.append(m)
                    line = joiner.feed(m)
                    if line is not None:
                        lines.append((m.severity, line))
        # a second sender on the same link (serve: one per request) goes on counting: its long line has another id
        assert StatusTexts(link).send(long, Severity.WARNING)
        more = []
        while len(more) < 2:
            more += [m for m in await raw_peer.recv(2.0) if m.get_type() == "STATUSTEXT"]
    assert lines == [(Severity.NOTICE, "plan accepted"), (Severity.WARNING, long)]
    assert all((m.get_srcSystem(), m.get_srcComponent()) == (1, 195) for m in raw)
    assert len(raw) == 3 and raw[1].id == raw[2].id != 0 and [m.chunk_seq for m in raw[1:]] == [0, 1]
    assert more[0].id == more[1].id not in (0, raw[1].id)
    assert out.sent == [(Severity.NOTICE, "plan accepted"), (Severity.WARNING, long)]


@pytest.mark.asyncio
async def test_a_closed_link_loses_the_line_without_raising():
    link = Link("udpout:127.0.0.1:9")  # never opened
    out = StatusTexts(link)
    assert out.send("failure: link lost", Severity.ERROR) is False
    assert out.sent == []
