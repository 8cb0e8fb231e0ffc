"""The sans-IO engine: a client engine wired to a server engine in memory."""

from __future__ import annotations

import pytest

from opendnc.errors import LocalProtocolError, PeerClosed, RemoteProtocolError
from opendnc.lsv2.connection import Lsv2Connection, Role, State, UndecodableTelegram
from opendnc.lsv2.messages import (
    BlockDefect,
    CommandDone,
    FileData,
    FileDone,
    Login,
    Message,
    Ok,
    ReadVersion,
    Refused,
    SystemCommand,
    VersionReply,
)


def pipe(src: Lsv2Connection, dst: Lsv2Connection, message: Message) -> Message | None:
    dst.receive_data(src.send(message))
    return dst.next_event()


def test_request_answer_and_trace() -> None:
    trace: list[tuple[str, Message]] = []
    client = Lsv2Connection(Role.CLIENT, on_message=lambda d, m: trace.append((d, m)))
    server = Lsv2Connection(Role.SERVER)
    assert pipe(client, server, Login("INSPECT")) == Login("INSPECT")
    assert client.state is State.WAITING
    with pytest.raises(LocalProtocolError, match="waiting"):
        client.send(ReadVersion())
    assert pipe(server, client, Ok()) == Ok()
    assert client.state is State.IDLE
    assert trace == [("send", Login("INSPECT")), ("recv", Ok())]


def test_unsolicited_answer_is_remote_error() -> None:
    client = Lsv2Connection(Role.CLIENT)
    server = Lsv2Connection(Role.SERVER)
    client.receive_data(server.send(Ok()))
    with pytest.raises(RemoteProtocolError, match="unsolicited T_OK"):
        client.next_event()


def test_unsolicited_m_cc_is_queued() -> None:
    client = Lsv2Connection(Role.CLIENT)
    server = Lsv2Connection(Role.SERVER)
    pipe(client, server, ReadVersion())
    client.receive_data(server.send(CommandDone(27, 100)) + server.send(VersionReply(("a",))))
    assert client.next_event() == VersionReply(("a",))
    assert client.next_notice() == CommandDone(27, 100)
    assert client.next_notice() is None
    # and while idle
    client.receive_data(server.send(CommandDone(27, 100)))
    assert client.next_event() is None
    assert client.next_notice() == CommandDone(27, 100)


def test_buffer_negotiation_both_sides() -> None:
    client = Lsv2Connection(Role.CLIENT)
    server = Lsv2Connection(Role.SERVER)
    big = FileData(b"x" * 1000)
    with pytest.raises(LocalProtocolError, match="buffer of 256"):
        client.send(big)
    pipe(client, server, SystemCommand(3))
    assert server.buffer_size == 256
    pipe(server, client, Ok())
    assert server.buffer_size == client.buffer_size == 1024
    # a refused buffer command changes nothing
    pipe(client, server, SystemCommand(7))
    pipe(server, client, Refused(24))
    assert server.buffer_size == client.buffer_size == 1024
    pipe(client, server, big)


def test_secure_send_decides_whether_t_fd_is_answered() -> None:
    client = Lsv2Connection(Role.CLIENT)
    server = Lsv2Connection(Role.SERVER)
    assert pipe(client, server, FileDone()) == FileDone()
    assert client.state is State.IDLE  # no answer expected without secure send
    pipe(client, server, SystemCommand(19))
    pipe(server, client, Ok())
    assert client.secure_send
    assert server.secure_send
    pipe(client, server, FileDone())
    assert client.state is State.WAITING
    pipe(server, client, Ok())
    pipe(client, server, BlockDefect())
    assert client.state is State.IDLE


def test_peer_closed() -> None:
    client = Lsv2Connection(Role.CLIENT)
    client.send(ReadVersion())
    client.receive_data(b"\x00\x00")
    assert client.next_event() is None
    client.receive_data(b"")
    with pytest.raises(PeerClosed, match="mid-telegram"):
        client.next_event()


def test_server_keeps_going_after_unknown_telegram() -> None:
    server = Lsv2Connection(Role.SERVER)
    server.receive_data(b"\x00\x00\x00\x00Q_QQ\x00\x00\x00\x00R_VR")
    with pytest.raises(UndecodableTelegram, match="unknown telegram") as info:
        server.next_event()
    assert info.value.frame.mnemonic == "Q_QQ"
    assert server.next_event() == ReadVersion()


def test_malformed_payload_is_an_undecodable_telegram_not_lost_framing() -> None:
    server = Lsv2Connection(Role.SERVER)
    server.receive_data(b"\x00\x00\x00\x01R_RI\x01")  # R_RI needs 2 bytes
    with pytest.raises(UndecodableTelegram) as info:
        server.next_event()
    assert (info.value.frame.mnemonic, info.value.frame.payload) == ("R_RI", b"\x01")


def test_lost_framing_is_not_an_undecodable_telegram() -> None:
    server = Lsv2Connection(Role.SERVER)
    server.receive_data(b"\x00\x00\x00\x00\xff\xfe\x00\x01")  # no telegram name
    with pytest.raises(RemoteProtocolError) as info:
        server.next_event()
    assert not isinstance(info.value, UndecodableTelegram)
