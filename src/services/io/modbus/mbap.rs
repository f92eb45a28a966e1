//! A Modbus TCP client that sends the requests of one exchange together and matches each
//! response to its request by transaction identifier ([`Pipelined::call_all`]).
//!
//! Why not tokio-modbus's TCP client: it sends a request, waits for its response, and only
//! then sends the next, so an exchange of four requests costs four round trips, and on a real
//! X20BC0087 (each answer 1–8 ms) four answers in a row can outlast the 10 ms cycle. The
//! Modbus TCP framing lets a client have several transactions open on one connection, told
//! apart by the MBAP header's transaction identifier. Responses are still decoded by
//! tokio-modbus (`Response::try_from`), which checks their lengths; only the requests are
//! encoded here. For a station that does not take pipelined requests, the I/O map's
//! `"requests": "sequential"` keeps tokio-modbus's client.

use std::io::{self, ErrorKind};
use std::time::Duration;

use tokio::time::Instant;

use tokio::io::{AsyncRead, AsyncReadExt as _, AsyncWrite, AsyncWriteExt as _};
use tokio_modbus::bytes::BytesMut;
use tokio_modbus::client::Client;
use tokio_modbus::slave::SlaveContext;
use tokio_modbus::{ExceptionCode, ExceptionResponse, Request, Response, Slave};

/// The MBAP header: transaction id, protocol id (0), length, unit id.
const HEADER_LEN: usize = 7;

/// The largest PDU of a Modbus frame.
const MAX_PDU: usize = 253;

/// What a request came back as: the response, or the station's exception.
pub(super) type Answer = Result<Response, ExceptionCode>;

/// A stream that can have the kernel acknowledge what it receives at once.
///
/// Why: a station that sends each answer in its own segment with Nagle's algorithm on holds
/// the second answer until the first is acknowledged, and Linux delays acknowledgements up to
/// 40 ms when the receiver has nothing to send back, which a pipelined client has not until
/// the last answer: four pipelined requests then took 44 ms instead of four round trips.
/// `TCP_QUICKACK`, set again after every read (the kernel leaves quick-ack mode by itself),
/// acknowledges each answer as it comes.
pub(super) trait QuickAck {
    /// Asks for immediate acknowledgements (best effort: nothing happens where it is unknown).
    fn quick_ack(&self) {}
}

impl QuickAck for crate::services::io::rx_counter::RxCounter<tokio::net::TcpStream> {
    fn quick_ack(&self) {
        // A socket option that cannot be set leaves the delayed acknowledgements: slower, not
        // wrong.
        let _ = socket2::SockRef::from(self.get_ref()).set_tcp_quickack(true);
    }
}

/// A Modbus TCP connection whose requests may be in flight together.
#[derive(Debug)]
pub(super) struct Pipelined<S> {
    stream: S,
    unit: u8,
    /// The transaction identifier of the next request.
    next_id: u16,
    /// The requests of the batch in flight, encoded.
    tx: Vec<u8>,
    /// Received bytes not yet made into responses (at most one frame's worth stays between
    /// reads: every complete frame is taken out at once).
    rx: BytesMut,
}

impl<S: AsyncRead + AsyncWrite + QuickAck + Unpin + Send> Pipelined<S> {
    /// A client on `stream`, addressing unit `unit` (0xFF: the TCP device itself).
    pub fn new(stream: S, unit: Slave) -> Self {
        Pipelined {
            stream,
            unit: unit.into(),
            next_id: 0,
            tx: Vec::with_capacity(4 * (HEADER_LEN + MAX_PDU)),
            rx: BytesMut::with_capacity(4 * (HEADER_LEN + MAX_PDU)),
        }
    }

    /// Sends every request of `requests` in one write and waits until each has its answer in
    /// `answers` (one per request, filled as they arrive, in whatever order the station sends
    /// them). With `patience`, each answer may take that long after the one before (after the
    /// sending, for the first), as if the requests had gone one after another: a station that
    /// works through them in turn is not cut short. Past it the call ends with `TimedOut`,
    /// `answers` showing which came. A response that answers no request in flight, another
    /// unit's or another function's, ends the call as a corrupt exchange (`InvalidData`); a
    /// closed connection as `UnexpectedEof`.
    pub async fn call_all(
        &mut self,
        requests: &[Request<'_>],
        answers: &mut [Option<Answer>],
        patience: Option<Duration>,
    ) -> io::Result<()> {
        assert_eq!(requests.len(), answers.len(), "one answer per request");
        let first = self.next_id;
        self.tx.clear();
        for (i, request) in requests.iter().enumerate() {
            encode_adu(&mut self.tx, first.wrapping_add(i as u16), self.unit, request)?;
        }
        self.next_id = first.wrapping_add(requests.len() as u16);
        answers.fill(None);
        // Bytes left from an earlier call belong to no request now in flight.
        self.rx.clear();
        let mut deadline = patience.map(|p| Instant::now() + p);
        self.stream.quick_ack();
        within(deadline, self.stream.write_all(&self.tx)).await?;
        let mut left = requests.len();
        while left > 0 {
            while let Some((id, unit, pdu)) = take_frame(&mut self.rx)? {
                let i = usize::from(id.wrapping_sub(first));
                let Some(slot) = answers.get_mut(i).filter(|a| a.is_none()) else {
                    return Err(invalid(format!(
                        "a response with transaction id {id}, which no request in flight has"
                    )));
                };
                if unit != self.unit {
                    return Err(invalid(format!(
                        "a response from unit {unit}, the request went to unit {}",
                        self.unit
                    )));
                }
                *slot = Some(decode_answer(pdu, requests[i].function_code().value())?);
                left -= 1;
                deadline = patience.map(|p| Instant::now() + p);
            }
            if left > 0 {
                let got = within(deadline, self.stream.read_buf(&mut self.rx)).await?;
                if got == 0 {
                    return Err(io::Error::new(
                        ErrorKind::UnexpectedEof,
                        "the station closed the connection",
                    ));
                }
                self.stream.quick_ack();
            }
        }
        Ok(())
    }

    /// Whether bytes of a response that is not complete are waiting: after a timeout, a
    /// station that sent something no frame could be made of.
    pub fn partial_response(&self) -> bool {
        !self.rx.is_empty()
    }
}

/// `f` until `deadline` (none: as long as it takes); past it, a `TimedOut` error.
async fn within<T>(deadline: Option<Instant>, f: impl Future<Output = io::Result<T>>) -> io::Result<T> {
    match deadline {
        None => f.await,
        Some(d) => tokio::time::timeout_at(d, f)
            .await
            .unwrap_or_else(|_| Err(io::Error::new(ErrorKind::TimedOut, "no answer in time"))),
    }
}

impl<S> SlaveContext for Pipelined<S> {
    fn set_slave(&mut self, slave: Slave) {
        self.unit = slave.into();
    }
}

/// One request at a time, for what is not an exchange (the bus controller's registers).
#[async_trait::async_trait]
impl<S: AsyncRead + AsyncWrite + QuickAck + Unpin + Send> Client for Pipelined<S> {
    async fn call(&mut self, request: Request<'_>) -> tokio_modbus::Result<Response> {
        let mut answer = [None];
        self.call_all(std::slice::from_ref(&request), &mut answer, None).await?;
        match answer {
            [Some(a)] => Ok(a),
            // `call_all` returns Ok only with every answer in.
            [None] => unreachable!("call_all returned without the answer"),
        }
    }

    async fn disconnect(&mut self) -> io::Result<()> {
        self.stream.shutdown().await
    }
}

fn invalid(message: String) -> io::Error {
    io::Error::new(ErrorKind::InvalidData, message)
}

/// Appends the frame of `request` with transaction id `id` to `out`.
fn encode_adu(out: &mut Vec<u8>, id: u16, unit: u8, request: &Request<'_>) -> io::Result<()> {
    let start = out.len();
    out.extend(id.to_be_bytes());
    out.extend([0, 0, 0, 0, unit]);
    if let Err(e) = encode_pdu(out, request) {
        out.truncate(start);
        return Err(e);
    }
    let pdu_len = out.len() - start - HEADER_LEN;
    if pdu_len > MAX_PDU {
        out.truncate(start);
        return Err(io::Error::new(
            ErrorKind::InvalidInput,
            format!("a request of {pdu_len} bytes, more than one frame carries ({MAX_PDU})"),
        ));
    }
    out[start + 4..start + 6].copy_from_slice(&(pdu_len as u16 + 1).to_be_bytes());
    Ok(())
}

/// Appends the PDU of `request` (function code first) to `out`; the functions the bus driver
/// sends, and an error for any other.
fn encode_pdu(out: &mut Vec<u8>, request: &Request<'_>) -> io::Result<()> {
    let words = |out: &mut Vec<u8>, w: &[u16]| {
        out.extend((w.len() as u16).to_be_bytes());
        out.push((2 * w.len()) as u8);
        out.extend(w.iter().flat_map(|w| w.to_be_bytes()));
    };
    out.push(request.function_code().value());
    match request {
        Request::ReadCoils(a, n)
        | Request::ReadDiscreteInputs(a, n)
        | Request::ReadInputRegisters(a, n)
        | Request::ReadHoldingRegisters(a, n)
        | Request::WriteSingleRegister(a, n) => {
            out.extend(a.to_be_bytes());
            out.extend(n.to_be_bytes());
        }
        Request::WriteSingleCoil(a, on) => {
            out.extend(a.to_be_bytes());
            out.extend(if *on { [0xFF, 0x00] } else { [0x00, 0x00] });
        }
        Request::WriteMultipleCoils(a, bits) => {
            out.extend(a.to_be_bytes());
            out.extend((bits.len() as u16).to_be_bytes());
            let bytes = bits.len().div_ceil(8);
            out.push(bytes as u8);
            let at = out.len();
            out.resize(at + bytes, 0);
            for (i, _) in bits.iter().enumerate().filter(|(_, b)| **b) {
                out[at + i / 8] |= 1 << (i % 8);
            }
        }
        Request::WriteMultipleRegisters(a, w) => {
            out.extend(a.to_be_bytes());
            words(out, w);
        }
        Request::ReadWriteMultipleRegisters(read, n, write, w) => {
            out.extend(read.to_be_bytes());
            out.extend(n.to_be_bytes());
            out.extend(write.to_be_bytes());
            words(out, w);
        }
        other => {
            return Err(io::Error::new(
                ErrorKind::InvalidInput,
                format!("{other:?}: a request the pipelined client does not send"),
            ));
        }
    }
    Ok(())
}

/// Takes the first complete frame out of `rx`: its transaction id, unit and PDU. `None` while
/// the frame is incomplete; an error when the bytes are not a Modbus TCP frame (the stream
/// cannot be resynchronised after one).
fn take_frame(rx: &mut BytesMut) -> io::Result<Option<(u16, u8, tokio_modbus::bytes::Bytes)>> {
    if rx.len() < HEADER_LEN {
        return Ok(None);
    }
    let len = usize::from(u16::from_be_bytes([rx[4], rx[5]]));
    if rx[2..4] != [0, 0] || !(2..=MAX_PDU + 1).contains(&len) {
        return Err(invalid(format!("not a Modbus TCP header: {:02x?}", &rx[..HEADER_LEN])));
    }
    if rx.len() < HEADER_LEN - 1 + len {
        return Ok(None);
    }
    let header = rx.split_to(HEADER_LEN);
    let pdu = rx.split_to(len - 1).freeze();
    Ok(Some((u16::from_be_bytes([header[0], header[1]]), header[6], pdu)))
}

/// The answer in `pdu` to a request of `function`: tokio-modbus decodes it and checks its
/// length.
fn decode_answer(pdu: tokio_modbus::bytes::Bytes, function: u8) -> io::Result<Answer> {
    let code = pdu[0];
    if code & 0x7F != function {
        return Err(invalid(format!(
            "a response of function {:#04x} to a request of function {function:#04x}",
            code & 0x7F
        )));
    }
    if code & 0x80 != 0 {
        let ExceptionResponse { exception, .. } = ExceptionResponse::try_from(pdu).map_err(undecodable)?;
        return Ok(Err(exception));
    }
    Ok(Ok(Response::try_from(pdu).map_err(undecodable)?))
}

/// A response tokio-modbus could not decode: corrupt, whatever its reader's error kind (a
/// short PDU reads as an unexpected end, which is not a closed connection).
fn undecodable(e: io::Error) -> io::Error {
    invalid(format!("a response that could not be decoded: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::services::sim::pdu::{decode_request, encode_response};
    use std::borrow::Cow;

    /// The requests the bus driver sends, as the station's own decoder reads them back.
    #[test]
    fn requests_encode_as_the_station_decodes_them() {
        let requests = [
            Request::ReadDiscreteInputs(0, 18),
            Request::ReadInputRegisters(0, 2),
            Request::WriteMultipleCoils(
                0,
                Cow::Owned(vec![true, false, true, true, false, false, false, false, true]),
            ),
            Request::WriteMultipleRegisters(0x0800, Cow::Owned(vec![1, 0xFFFF, 0x1234])),
            Request::ReadHoldingRegisters(0xA000, 112),
            Request::WriteSingleRegister(0x1040, 50),
            Request::WriteSingleCoil(7, true),
            Request::ReadWriteMultipleRegisters(0, 4, 0x100, Cow::Owned(vec![9, 8])),
        ];
        for (id, request) in requests.iter().enumerate() {
            let mut frame = Vec::new();
            encode_adu(&mut frame, id as u16 + 300, 0xFF, request).unwrap();
            assert_eq!(frame[..2], (id as u16 + 300).to_be_bytes());
            assert_eq!(usize::from(u16::from_be_bytes([frame[4], frame[5]])), frame.len() - 6);
            assert_eq!(frame[6], 0xFF);
            assert_eq!(&decode_request(&frame[HEADER_LEN..]).unwrap(), request);
        }
    }

    #[test]
    fn other_requests_and_oversized_ones_are_refused_before_sending() {
        let mut out = vec![1, 2, 3];
        let e = encode_adu(&mut out, 0, 0xFF, &Request::ReportServerId).unwrap_err();
        assert_eq!(
            e.to_string(),
            "ReportServerId: a request the pipelined client does not send"
        );
        let e = encode_adu(
            &mut out,
            0,
            0xFF,
            &Request::WriteMultipleRegisters(0, Cow::Owned(vec![0; 200])),
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "a request of 406 bytes, more than one frame carries (253)"
        );
        assert_eq!(out, [1, 2, 3], "nothing of a refused request stays");
    }

    /// A response frame as a station sends it.
    fn response(id: u16, unit: u8, function: u8, answer: &Answer) -> Vec<u8> {
        let mut pdu = Vec::new();
        encode_response(function, answer, &mut pdu);
        let mut frame = id.to_be_bytes().to_vec();
        frame.extend([0, 0]);
        frame.extend((pdu.len() as u16 + 1).to_be_bytes());
        frame.push(unit);
        frame.extend(pdu);
        frame
    }

    impl QuickAck for tokio::io::DuplexStream {}

    /// A client on one end of a duplex pipe; the test plays the station on the other.
    fn pair() -> (Pipelined<tokio::io::DuplexStream>, tokio::io::DuplexStream) {
        let (a, b) = tokio::io::duplex(4096);
        (Pipelined::new(a, Slave(0xFF)), b)
    }

    /// Reads `n` request frames off the station's end: their transaction ids.
    async fn request_ids(station: &mut tokio::io::DuplexStream, n: usize) -> Vec<u16> {
        let mut ids = Vec::new();
        for _ in 0..n {
            let mut header = [0u8; HEADER_LEN];
            station.read_exact(&mut header).await.unwrap();
            let mut pdu = vec![0u8; usize::from(u16::from_be_bytes([header[4], header[5]])) - 1];
            station.read_exact(&mut pdu).await.unwrap();
            ids.push(u16::from_be_bytes([header[0], header[1]]));
        }
        ids
    }

    #[tokio::test]
    async fn answers_in_any_order_reach_their_requests() {
        let (mut client, mut station) = pair();
        let requests = [
            Request::ReadDiscreteInputs(0, 3),
            Request::ReadInputRegisters(0, 2),
            Request::WriteMultipleRegisters(0x0800, Cow::Owned(vec![5])),
        ];
        let mut answers = [None, None, None];
        let serve = async {
            let ids = request_ids(&mut station, 3).await;
            // All three were sent before any answer: the station answers the last first, and
            // refuses the first.
            let mut out = response(ids[2], 0xFF, 0x10, &Ok(Response::WriteMultipleRegisters(0x0800, 1)));
            out.extend(response(
                ids[1],
                0xFF,
                0x04,
                &Ok(Response::ReadInputRegisters(vec![7, 8])),
            ));
            out.extend(response(ids[0], 0xFF, 0x02, &Err(ExceptionCode::ServerDeviceBusy)));
            station.write_all(&out).await.unwrap();
            ids
        };
        let (ids, sent) = tokio::join!(serve, client.call_all(&requests, &mut answers, None));
        sent.unwrap();
        assert_eq!(ids, [0, 1, 2]);
        assert_eq!(
            answers,
            [
                Some(Err(ExceptionCode::ServerDeviceBusy)),
                Some(Ok(Response::ReadInputRegisters(vec![7, 8]))),
                Some(Ok(Response::WriteMultipleRegisters(0x0800, 1))),
            ]
        );
        // The next batch goes on from the next transaction id, answered byte by byte.
        let serve = async {
            let ids = request_ids(&mut station, 1).await;
            for byte in response(ids[0], 0xFF, 0x04, &Ok(Response::ReadInputRegisters(vec![1, 2]))) {
                station.write_all(&[byte]).await.unwrap();
            }
            ids
        };
        let (ids, answer) = tokio::join!(serve, client.call(Request::ReadInputRegisters(0, 2)));
        assert_eq!(ids, [3]);
        assert_eq!(answer.unwrap(), Ok(Response::ReadInputRegisters(vec![1, 2])));
    }

    /// A station's answer, made for the transaction id of the request.
    type FrameFor<'a> = Box<dyn Fn(u16) -> Vec<u8> + 'a>;

    /// What the call ends with when the station answers `frame` to a request for two input
    /// registers.
    async fn outcome_of(frame: impl Fn(u16) -> Vec<u8>) -> io::Result<()> {
        let (mut client, mut station) = pair();
        let mut answers = [None];
        let serve = async {
            let ids = request_ids(&mut station, 1).await;
            station.write_all(&frame(ids[0])).await.unwrap();
            // Closed after its answer: a call still waiting then ends.
            drop(station);
        };
        let ((), result) = tokio::join!(
            serve,
            client.call_all(&[Request::ReadInputRegisters(0, 2)], &mut answers, None)
        );
        result
    }

    #[tokio::test]
    async fn a_response_that_answers_nothing_in_flight_is_corrupt() {
        let regs = Ok(Response::ReadInputRegisters(vec![1, 2]));
        let cases: [(FrameFor<'_>, &str); 5] = [
            (
                Box::new(|id| response(id.wrapping_add(1), 0xFF, 0x04, &regs)),
                "a response with transaction id 1, which no request in flight has",
            ),
            (
                Box::new(|id| response(id, 3, 0x04, &regs)),
                "a response from unit 3, the request went to unit 255",
            ),
            (
                Box::new(|id| response(id, 0xFF, 0x03, &Ok(Response::ReadHoldingRegisters(vec![1, 2])))),
                "a response of function 0x03 to a request of function 0x04",
            ),
            (
                Box::new(|id| {
                    let mut f = response(id, 0xFF, 0x04, &regs);
                    f[2] = 1;
                    f
                }),
                "not a Modbus TCP header: [00, 00, 01, 00, 00, 07, ff]",
            ),
            (
                // A byte count that promises more than the frame has.
                Box::new(|id| {
                    let mut f = response(id, 0xFF, 0x04, &regs);
                    f[8] = 40;
                    f
                }),
                "a response that could not be decoded: failed to fill whole buffer",
            ),
        ];
        for (frame, message) in cases {
            let e = outcome_of(frame).await.unwrap_err();
            assert_eq!(e.kind(), ErrorKind::InvalidData, "{e}");
            if !message.is_empty() {
                assert_eq!(e.to_string(), message);
            }
        }
    }

    #[tokio::test]
    async fn a_station_that_closes_mid_batch_is_a_lost_connection() {
        let e = outcome_of(|id| response(id, 0xFF, 0x04, &Ok(Response::ReadInputRegisters(vec![1, 2])))[..9].to_vec())
            .await
            .unwrap_err();
        assert_eq!(e.kind(), ErrorKind::UnexpectedEof);
        assert_eq!(e.to_string(), "the station closed the connection");
    }

    /// A station that works through the requests in turn, each answer 30 ms after the one
    /// before: with 50 ms of patience all three come (90 ms in all); one that stops answering
    /// ends the call 50 ms after its last answer, the answers so far kept.
    #[tokio::test(start_paused = true)]
    async fn patience_runs_from_the_last_answer() {
        for stop_after in [3, 1] {
            let (mut client, mut station) = pair();
            let requests = [
                Request::ReadInputRegisters(0, 1),
                Request::ReadInputRegisters(1, 1),
                Request::ReadInputRegisters(2, 1),
            ];
            let mut answers = [None, None, None];
            let started = Instant::now();
            let serve = async {
                let ids = request_ids(&mut station, 3).await;
                for &id in &ids[..stop_after] {
                    tokio::time::sleep(Duration::from_millis(30)).await;
                    let frame = response(id, 0xFF, 0x04, &Ok(Response::ReadInputRegisters(vec![id])));
                    station.write_all(&frame).await.unwrap();
                }
                station
            };
            let patience = Some(Duration::from_millis(50));
            let (_station, result) = tokio::join!(serve, client.call_all(&requests, &mut answers, patience));
            let took = started.elapsed();
            if stop_after == 3 {
                result.unwrap();
                assert_eq!(took, Duration::from_millis(90));
                assert_eq!(answers[2], Some(Ok(Response::ReadInputRegisters(vec![2]))));
            } else {
                assert_eq!(result.unwrap_err().kind(), ErrorKind::TimedOut);
                assert_eq!(took, Duration::from_millis(80));
                assert_eq!(answers, [Some(Ok(Response::ReadInputRegisters(vec![0]))), None, None]);
                assert!(!client.partial_response());
            }
        }
    }
}
