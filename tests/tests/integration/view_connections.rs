//! Issue 43 (6): `sdictl view`'s connections. Idle connections, headers
//! that never end and bodies that never arrive are closed after the timeout
//! (`SDI_VIEW_TIMEOUT_MS`, shortened here); connections that have shown no
//! token are capped, so a flood of them (here under a file limit of 64)
//! neither exhausts sdictl's descriptors nor keeps the page out.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::process::Command;
use std::time::{Duration, Instant};

use sdi_tests::dbus::{bin, Bus, Daemon};
use sdi_tests::require_dbus;

use super::view_page::View;

fn connect(v: &View) -> TcpStream {
    let s = TcpStream::connect(("127.0.0.1", v.port)).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    s
}

/// Reads one response's head and its `Content-Length` body; returns the status.
fn read_response(s: &mut TcpStream) -> u16 {
    let mut head = Vec::new();
    let mut byte = [0u8; 1];
    while !head.ends_with(b"\r\n\r\n") {
        s.read_exact(&mut byte).expect("a response");
        head.push(byte[0]);
    }
    let head = String::from_utf8_lossy(&head).into_owned();
    let length: usize = head
        .lines()
        .find_map(|l| {
            l.to_ascii_lowercase()
                .strip_prefix("content-length:")
                .map(|n| n.trim().parse().unwrap())
        })
        .unwrap_or(0);
    let mut body = vec![0u8; length];
    s.read_exact(&mut body).unwrap();
    head[9..12].parse().expect(&head)
}

/// Whether the server closed `s` (EOF, or a reset) before its read timeout,
/// after whatever response it sent.
fn closed_by_server(s: &mut TcpStream) -> bool {
    let mut buf = [0u8; 4096];
    loop {
        match s.read(&mut buf) {
            Ok(0) => return true,
            Ok(_) => continue,
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => return true,
            Err(_) => return false,
        }
    }
}

#[test]
fn idle_connections_unfinished_headers_and_missing_bodies_are_closed() {
    require_dbus!();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &[]);
    let dir = tempfile::tempdir().unwrap();
    let v = View::start_with(&d, dir.path(), &[("SDI_VIEW_TIMEOUT_MS", "1000")]);
    let host = format!("127.0.0.1:{}", v.port);
    let t0 = Instant::now();
    let mut cases: Vec<(String, TcpStream)> = Vec::new();
    for i in 0..10 {
        cases.push((format!("idle {i}"), connect(&v)));
    }
    let mut s = connect(&v);
    s.write_all(format!("GET /?token={} HTTP/1.1\r\nHost: {host}\r\n", v.token).as_bytes())
        .unwrap();
    cases.push(("headers without their end".into(), s));
    let mut s = connect(&v);
    s.write_all(
        format!(
            "GET /api/status?token={} HTTP/1.1\r\nHost: {host}\r\n\r\n",
            v.token
        )
        .as_bytes(),
    )
    .unwrap();
    assert_eq!(read_response(&mut s), 200);
    cases.push(("kept alive after a response".into(), s));
    let mut s = connect(&v);
    s.write_all(
        format!(
            "POST /api/set?token={} HTTP/1.1\r\nHost: {host}\r\nOrigin: http://{host}\r\n\
             Content-Type: application/json\r\nContent-Length: 100\r\n\r\n{{\"setting\"",
            v.token
        )
        .as_bytes(),
    )
    .unwrap();
    cases.push(("a body that never arrives".into(), s));
    for (what, s) in &mut cases {
        assert!(
            closed_by_server(s),
            "{what}: still open {:?} after it was opened",
            t0.elapsed()
        );
    }
    // The server itself still serves.
    assert_eq!(v.status().0, 200);
}

#[test]
fn with_the_cap_reached_the_page_still_gets_its_status_and_frames() {
    require_dbus!();
    let bus = Bus::start();
    let d = Daemon::start(&bus, &[]);
    let dir = tempfile::tempdir().unwrap();
    let v = View::spawn(
        Command::new("prlimit")
            .arg("--nofile=64")
            .arg(bin("sdictl"))
            .args(View::args(&d, dir.path())),
    );
    let host = format!("127.0.0.1:{}", v.port);
    // The page's WebSocket, open before the flood.
    let mut ws = connect(&v);
    ws.write_all(
        format!(
            "GET /ws?token={} HTTP/1.1\r\nHost: {host}\r\nOrigin: http://{host}\r\n\
             Upgrade: websocket\r\nConnection: Upgrade\r\n\
             Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n",
            v.token
        )
        .as_bytes(),
    )
    .unwrap();
    assert_eq!(read_response(&mut ws), 101);
    // 200 connections that never show a token.
    let flood: Vec<TcpStream> = (0..200).map(|_| connect(&v)).collect();
    // A new authenticated request is served...
    let (status, reply) = v.status();
    assert_eq!(status, 200, "{reply}");
    // ...and the WebSocket still carries frames.
    let mut buf = [0u8; 4096];
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut got = 0;
    while got < 100_000 {
        let n = ws.read(&mut buf).expect("frames on the page's WebSocket");
        assert!(n > 0, "the page's WebSocket was closed");
        got += n;
        assert!(Instant::now() < deadline, "the WebSocket stalled");
    }
    drop(flood);
}
