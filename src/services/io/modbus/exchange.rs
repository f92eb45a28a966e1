//! One exchange with the station: every input read, every output written, in one of the two
//! [`ExchangeMode`]s, with each request's outcome sorted into what the link counts ([`Failure`]).
//! Also what an exchange costs on the wire ([`WireLoad`]), and the open link it runs on
//! ([`Connection`]).

use std::borrow::Cow;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use tokio::net::TcpStream;
use tokio_modbus::client::{self, Client};
use tokio_modbus::{Request, Response};

use super::ExchangeMode;
use super::mbap::{Answer, Pipelined};
use crate::image::{Value, VarIndex, VarType};
use crate::services::io::map::Requests;
use crate::services::io::registers::{
    INPUT_IMAGE, ImageLayout, OUTPUT_IMAGE, RegisterMap, Table, decode, encode, pack_bits, packed_bit,
};
use crate::services::io::rx_counter::RxCounter;
use crate::services::io::x20bc0087::ExpectedModule;

/// A binding as the driver sees it: where its channel lives and which variable it is.
#[derive(Clone, Copy, Debug)]
pub(super) struct Slot {
    /// Index into the register map's entries (to follow an X20BC0087's own data indexes).
    pub entry: usize,
    pub table: Table,
    pub address: u16,
    pub count: u16,
    pub ty: VarType,
    pub var: VarIndex,
}

/// Why one exchange failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Failure {
    /// No response in time, nothing received.
    Timeout,
    /// A response that could not be decoded: bytes arrived, no valid frame (a bad CRC, garbage).
    Corrupt,
    /// An exception response.
    Exception,
    /// The connection or port is gone.
    Disconnected,
}

/// A failed exchange: what the link counts, and what happened — the request, the exception's
/// code, the operating system's error — for the fault's cause.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) struct Failed {
    pub kind: Failure,
    pub cause: String,
}

impl From<Failure> for Failed {
    fn from(kind: Failure) -> Failed {
        Failed {
            kind,
            cause: kind.describe().to_string(),
        }
    }
}

impl Failure {
    /// What the failure was, for a fault's cause.
    pub(super) fn describe(self) -> &'static str {
        match self {
            Failure::Timeout => "no response within the timeout",
            Failure::Corrupt => "a response that could not be decoded",
            Failure::Exception => "an exception response",
            Failure::Disconnected => "the connection was lost or refused",
        }
    }
}

/// An open link to the station.
pub(super) enum Connection {
    /// tokio-modbus's client, one request at a time: a serial line, or Modbus TCP with
    /// `"requests": "sequential"` in the I/O map.
    Sequential(client::Context),
    /// Modbus TCP with the requests of an exchange sent together.
    Pipelined(Pipelined<RxCounter<TcpStream>>),
}

impl Connection {
    /// The link as a client that sends one request and waits for its answer.
    pub fn client(&mut self) -> &mut dyn Client {
        match self {
            Connection::Sequential(c) => c,
            Connection::Pipelined(p) => p,
        }
    }
}

/// What is exchanged and how: the input and output slots, the table sizes, the mode (never
/// `Auto`) and the timeout of each request.
pub(super) struct Exchange {
    pub mode: ExchangeMode,
    /// How the requests go over Modbus TCP (on a serial line, one at a time whatever it says).
    pub requests: Requests,
    /// Set when requests sent together were answered only in part before the timeout: the
    /// station keeps only the first of pipelined requests (pymodbus's server does). The link
    /// then goes on with one request at a time ([`Exchange::pipelining_refused`]).
    pub refused_pipelining: std::cell::Cell<bool>,
    pub timeout: Duration,
    pub inputs: Vec<Slot>,
    pub outputs: Vec<Slot>,
    /// `[coils, discrete inputs, input registers, holding registers]`.
    pub sizes: [u16; 4],
    /// The wire address of holding register 0 of the slots (0x0800 on an X20BC0087).
    pub holding_base: u16,
    /// On an X20BC0087: what its module table must hold and how its watchdog is set.
    pub bus_controller: Option<BusController>,
}

/// An X20BC0087 station as the I/O map describes it.
pub(super) struct BusController {
    /// The map's layout, before the station's own data indexes are known.
    pub registers: RegisterMap,
    /// What each slot must hold.
    pub expected: Vec<ExpectedModule>,
    /// The watchdog threshold set at every connection (ms).
    pub watchdog_ms: u16,
}

impl Exchange {
    /// One exchange: every input read into `in_values` (one per input slot), every output of
    /// `out_values` (one per output slot) written — unless `write` is false (the cycle has
    /// stopped publishing outputs): then the inputs are only read, and the station's watchdog
    /// is left to act. `received` counts the bytes received on the link.
    pub async fn run(
        &self,
        link: &mut Connection,
        received: &AtomicU64,
        in_values: &mut [Value],
        out_values: Option<&[Value]>,
    ) -> Result<(), Failed> {
        match (self.mode, link) {
            (ExchangeMode::Image, link) => self.image(link.client(), received, in_values, out_values).await,
            (_, Connection::Pipelined(p)) => self.pipelined(p, in_values, out_values).await,
            (_, Connection::Sequential(ctx)) => self.tables(ctx, received, in_values, out_values).await,
        }
    }

    /// Whether the last exchange found the station answering only part of the requests sent
    /// together (cleared by asking).
    pub fn pipelining_refused(&self) -> bool {
        self.refused_pipelining.take()
    }

    /// Moves every slot to where `registers` (the map's layout with a station's own data
    /// indexes) puts its channel, and the table sizes with them.
    pub fn rebase(&mut self, registers: &RegisterMap) {
        for slot in self.inputs.iter_mut().chain(self.outputs.iter_mut()) {
            if let Some(e) = registers.entries.get(slot.entry) {
                slot.address = e.address;
            }
        }
        self.sizes = registers.sizes();
    }

    /// The packed process image in one read/write-multiple-registers transaction.
    async fn image(
        &self,
        ctx: &mut dyn Client,
        received: &AtomicU64,
        in_values: &mut [Value],
        out_values: Option<&[Value]>,
    ) -> Result<(), Failed> {
        let layout = ImageLayout::of(self.sizes);
        let (request, what) = match out_values {
            Some(out_values) => {
                let (coil_bits, mut holding) = self.output_tables(out_values);
                let mut out_image = vec![0u16; usize::from(layout.output_bits)];
                pack_bits(&coil_bits, &mut out_image);
                out_image.append(&mut holding);
                (
                    Request::ReadWriteMultipleRegisters(INPUT_IMAGE, layout.input_len, OUTPUT_IMAGE, out_image.into()),
                    format!(
                        "read/write registers (the packed image: {} words read at {INPUT_IMAGE}, written at {OUTPUT_IMAGE})",
                        layout.input_len
                    ),
                )
            }
            None => (
                Request::ReadHoldingRegisters(INPUT_IMAGE, layout.input_len),
                format!(
                    "read holding registers (the packed input image: {} words at {INPUT_IMAGE})",
                    layout.input_len
                ),
            ),
        };
        let image = read_exactly(self.timeout, received, ctx, request, layout.input_len, &what)
            .await?
            .words()?;
        let (bits, regs) = image.split_at(usize::from(layout.input_bits));
        Ok(self.decode_inputs(in_values, |a| packed_bit(bits, a), regs)?)
    }

    /// The exchange's requests on the standard tables, in the order they go — read discrete
    /// inputs, read input registers, then, with `outputs` (the coils and holding registers of
    /// [`Exchange::output_tables`]), write coils and write holding registers — each with its
    /// name for a failure's cause. Tables without entries get no request.
    fn table_requests<'a>(&self, outputs: Option<&'a (Vec<bool>, Vec<u16>)>) -> Vec<(Request<'a>, String)> {
        let [coils, discrete, input_regs, holding] = self.sizes;
        let mut requests = Vec::with_capacity(4);
        if discrete > 0 {
            requests.push((
                Request::ReadDiscreteInputs(0, discrete),
                span("read discrete inputs", discrete),
            ));
        }
        if input_regs > 0 {
            requests.push((
                Request::ReadInputRegisters(0, input_regs),
                span("read input registers", input_regs),
            ));
        }
        if let Some((coil_bits, words)) = outputs {
            if coils > 0 {
                let request = Request::WriteMultipleCoils(0, Cow::Borrowed(&coil_bits[..]));
                requests.push((request, span("write coils", coils)));
            }
            if holding > 0 {
                let base = self.holding_base;
                let what = format!("write holding registers {base} … {}", base + holding - 1);
                requests.push((Request::WriteMultipleRegisters(base, Cow::Borrowed(&words[..])), what));
            }
        }
        requests
    }

    /// The four standard tables' requests sent together ([`Pipelined::call_all`]); each answer
    /// may take one request timeout after the one before.
    async fn pipelined(
        &self,
        link: &mut Pipelined<RxCounter<TcpStream>>,
        in_values: &mut [Value],
        out_values: Option<&[Value]>,
    ) -> Result<(), Failed> {
        let outputs = out_values.map(|v| self.output_tables(v));
        let requests = self.table_requests(outputs.as_ref());
        if requests.is_empty() {
            return Ok(());
        }
        let (sent, names): (Vec<Request<'_>>, Vec<String>) = requests.into_iter().unzip();
        let mut answers: Vec<Option<Answer>> = vec![None; sent.len()];
        let outcome = link.call_all(&sent, &mut answers, Some(self.timeout)).await;
        // The requests still without an answer, for a failure's cause: the first by name.
        let unanswered = || {
            let mut open = names.iter().zip(&answers).filter(|(_, a)| a.is_none()).map(|(n, _)| n);
            let first = open.next().map_or("the exchange", String::as_str);
            match open.count() {
                0 => first.to_string(),
                1 => format!("{first} and the request sent with it"),
                more => format!("{first} and the {more} requests sent with it"),
            }
        };
        match outcome {
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {
                // Some answered, the others never: the station does not keep requests that
                // arrive while it answers one.
                let answered = answers.iter().filter(|a| a.is_some()).count();
                if answered > 0 && answered < answers.len() {
                    self.refused_pipelining.set(true);
                }
                return Err(timed_out(self.timeout, link.partial_response(), &unanswered()));
            }
            Err(e) => return Err(transport_failure(&unanswered(), e)),
            Ok(()) => {}
        }
        let mut reads = TableReads::default();
        for ((request, what), answer) in sent.iter().zip(&names).zip(answers) {
            // `call_all` returned Ok: every request has its answer.
            let Some(answer) = answer else {
                unreachable!("an answer missing after call_all")
            };
            reads.take(request, what, answer.map_err(|code| exception(code, what))?)?;
        }
        Ok(self.decode_inputs(in_values, |a| reads.bits[a], &reads.regs)?)
    }

    /// The four standard tables, one request each, each after the answer to the one before.
    async fn tables(
        &self,
        ctx: &mut dyn Client,
        received: &AtomicU64,
        in_values: &mut [Value],
        out_values: Option<&[Value]>,
    ) -> Result<(), Failed> {
        let outputs = out_values.map(|v| self.output_tables(v));
        let mut reads = TableReads::default();
        for (request, what) in self.table_requests(outputs.as_ref()) {
            let response = within(self.timeout, received, &what, ctx.call(request.clone())).await?;
            reads.take(&request, &what, response)?;
        }
        Ok(self.decode_inputs(in_values, |a| reads.bits[a], &reads.regs)?)
    }

    /// The input values from the discrete inputs (by address) and the input registers.
    fn decode_inputs(&self, in_values: &mut [Value], bit: impl Fn(usize) -> bool, regs: &[u16]) -> Result<(), Failure> {
        for (slot, value) in self.inputs.iter().zip(in_values.iter_mut()) {
            let a = usize::from(slot.address);
            *value = match slot.table {
                Table::DiscreteInput => Value::Bool(bit(a)),
                _ => match regs.get(a..a + usize::from(slot.count)) {
                    Some(words) => decode(slot.ty, words),
                    // Lengths were checked on receipt; a register map that does not cover its
                    // own slots is a broken invariant, reported as a corrupt exchange anyway.
                    None => return Err(Failure::Corrupt),
                },
            };
        }
        Ok(())
    }

    /// The coils and holding registers that carry the output values.
    fn output_tables(&self, out_values: &[Value]) -> (Vec<bool>, Vec<u16>) {
        let [coils, _, _, holding] = self.sizes;
        let mut coil_bits = vec![false; usize::from(coils)];
        let mut words = vec![0u16; usize::from(holding)];
        for (slot, value) in self.outputs.iter().zip(out_values) {
            let a = usize::from(slot.address);
            match slot.table {
                Table::Coil => coil_bits[a] = *value == Value::Bool(true),
                _ => encode(*value, &mut words[a..a + usize::from(slot.count)]),
            }
        }
        (coil_bits, words)
    }
}

/// What the reads of a standard-tables exchange brought.
#[derive(Default)]
struct TableReads {
    /// The discrete inputs.
    bits: Vec<bool>,
    /// The input registers.
    regs: Vec<u16>,
}

impl TableReads {
    /// Takes the station's `response` to `request` (named `what`): a read's bits or words,
    /// their number checked; a write's echo checked.
    fn take(&mut self, request: &Request<'_>, what: &str, response: Response) -> Result<(), Failed> {
        match request {
            Request::ReadDiscreteInputs(_, n) => self.bits = checked_read(response, *n, what)?.bits()?,
            Request::ReadInputRegisters(_, n) => self.regs = checked_read(response, *n, what)?.words()?,
            _ => check_echo(request, &response, what)?,
        }
        Ok(())
    }
}

/// A request on `n` items from address 0, as a fault's cause names it.
fn span(request: &str, n: u16) -> String {
    format!("{request} 0 … {}", n.saturating_sub(1))
}

/// What a read request returned, its length checked.
enum Read {
    /// Bits of a read-bits response (exactly the quantity asked for).
    Bits(Vec<bool>),
    /// Words of a read-registers or read/write-registers response (exactly the quantity asked for).
    Words(Vec<u16>),
}

impl Read {
    fn bits(self) -> Result<Vec<bool>, Failure> {
        match self {
            Read::Bits(b) => Ok(b),
            Read::Words(_) => Err(Failure::Corrupt),
        }
    }

    fn words(self) -> Result<Vec<u16>, Failure> {
        match self {
            Read::Words(w) => Ok(w),
            Read::Bits(_) => Err(Failure::Corrupt),
        }
    }
}

/// Sends a read `request` for `quantity` bits or words and checks that the response carries
/// exactly that many: a response of the wrong length is a corrupt exchange, never "the rest are
/// false" (tokio-modbus's typed readers only `debug_assert` the length, which would panic a
/// debug build and pass a short response in a release build).
async fn read_exactly(
    t: Duration,
    received: &AtomicU64,
    ctx: &mut dyn Client,
    request: Request<'_>,
    quantity: u16,
    what: &str,
) -> Result<Read, Failed> {
    let response = within(t, received, what, ctx.call(request)).await?;
    checked_read(response, quantity, what)
}

/// Whether the response to a write request echoes its address and quantity, as the
/// specification has it.
fn check_echo(request: &Request<'_>, response: &Response, what: &str) -> Result<(), Failed> {
    let echoed = match (request, response) {
        (Request::WriteMultipleCoils(a, bits), Response::WriteMultipleCoils(b, n)) => {
            a == b && bits.len() == usize::from(*n)
        }
        (Request::WriteMultipleRegisters(a, words), Response::WriteMultipleRegisters(b, n)) => {
            a == b && words.len() == usize::from(*n)
        }
        _ => false,
    };
    if echoed {
        Ok(())
    } else {
        Err(Failed {
            kind: Failure::Corrupt,
            cause: format!("a response to {what} that does not echo it: {response:?}"),
        })
    }
}

/// The response to a read for `quantity` bits or words, its length checked.
fn checked_read(response: Response, quantity: u16, what: &str) -> Result<Read, Failed> {
    let n = usize::from(quantity);
    let got = match &response {
        Response::ReadCoils(b) | Response::ReadDiscreteInputs(b) => b.len(),
        Response::ReadInputRegisters(w)
        | Response::ReadHoldingRegisters(w)
        | Response::ReadWriteMultipleRegisters(w) => w.len(),
        _ => 0,
    };
    let short = Failed {
        kind: Failure::Corrupt,
        cause: format!("a response to {what} with {got} values, not the {quantity} asked for (another register map?)"),
    };
    match response {
        // Bits come packed: the response's byte count times 8, padding included.
        Response::ReadCoils(mut bits) | Response::ReadDiscreteInputs(mut bits) if bits.len() == n.div_ceil(8) * 8 => {
            bits.truncate(n);
            Ok(Read::Bits(bits))
        }
        Response::ReadInputRegisters(words)
        | Response::ReadHoldingRegisters(words)
        | Response::ReadWriteMultipleRegisters(words)
            if words.len() == n =>
        {
            Ok(Read::Words(words))
        }
        _ => Err(short),
    }
}

/// A request (`what`) under a timeout, its outcome sorted into what the loop counts, with its
/// cause; `received` counts the bytes received on the link.
async fn within<T>(
    t: Duration,
    received: &AtomicU64,
    what: &str,
    f: impl std::future::Future<Output = Result<Result<T, tokio_modbus::ExceptionCode>, tokio_modbus::Error>>,
) -> Result<T, Failed> {
    let before = received.load(Ordering::Relaxed);
    match tokio::time::timeout(t, f).await {
        Err(_) => Err(timed_out(t, received.load(Ordering::Relaxed) != before, what)),
        Ok(Err(tokio_modbus::Error::Transport(e))) => Err(transport_failure(what, e)),
        Ok(Err(e)) => Err(Failed {
            kind: Failure::Disconnected,
            cause: format!("{what}: {e}"),
        }),
        Ok(Ok(Err(code))) => Err(exception(code, what)),
        Ok(Ok(Ok(v))) => Ok(v),
    }
}

/// No answer to `what` within `t`; `bytes_came`: bytes arrived meanwhile.
fn timed_out(t: Duration, bytes_came: bool, what: &str) -> Failed {
    match bytes_came {
        // The RTU decoder drops bytes with a bad CRC and waits on: bytes but no frame.
        true => Failed {
            kind: Failure::Corrupt,
            cause: format!(
                "bytes but no valid response to {what} within {} ms (a bad CRC, another speed?)",
                t.as_millis()
            ),
        },
        false => Failed {
            kind: Failure::Timeout,
            cause: format!("no response to {what} within {} ms", t.as_millis()),
        },
    }
}

/// The link's error `e` while waiting for `what`: undecodable bytes, or a lost connection.
fn transport_failure(what: &str, e: std::io::Error) -> Failed {
    match e.kind() {
        std::io::ErrorKind::InvalidData => Failed {
            kind: Failure::Corrupt,
            cause: format!("a response to {what} that could not be decoded: {e}"),
        },
        _ => Failed {
            kind: Failure::Disconnected,
            cause: format!("{what}: {e}"),
        },
    }
}

/// The station's exception `code` to `what`.
fn exception(code: tokio_modbus::ExceptionCode, what: &str) -> Failed {
    Failed {
        kind: Failure::Exception,
        cause: format!("exception {} ({code}) to {what}", u8::from(code)),
    }
}

/// What one exchange puts on the wire.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WireLoad {
    /// Request/response transactions.
    pub transactions: u32,
    /// Bytes of all RTU frames, both directions (address, function, data, CRC).
    pub bytes: u32,
}

impl WireLoad {
    /// The load of one exchange in `mode` (not `Auto`) for table sizes `[coils, discrete inputs,
    /// input registers, holding registers]`, as Modbus RTU frames.
    pub fn of(mode: ExchangeMode, sizes: [u16; 4]) -> WireLoad {
        let [coils, discrete, input, holding] = sizes.map(u32::from);
        // Address, function and CRC: 4 bytes around every PDU.
        let read_bits = |n: u32| (n > 0).then(|| (4 + 4) + (4 + 1 + n.div_ceil(8)));
        let read_regs = |n: u32| (n > 0).then(|| (4 + 4) + (4 + 1 + 2 * n));
        let write_bits = |n: u32| (n > 0).then(|| (4 + 5 + n.div_ceil(8)) + (4 + 4));
        let write_regs = |n: u32| (n > 0).then(|| (4 + 5 + 2 * n) + (4 + 4));
        let frames: Vec<u32> = match mode {
            ExchangeMode::Image => {
                let layout = ImageLayout::of(sizes);
                let (i, o) = (u32::from(layout.input_len), u32::from(layout.output_len));
                vec![(4 + 9 + 2 * o) + (4 + 1 + 2 * i)]
            }
            ExchangeMode::Tables | ExchangeMode::Auto => [
                read_bits(discrete),
                read_regs(input),
                write_bits(coils),
                write_regs(holding),
            ]
            .into_iter()
            .flatten()
            .collect(),
        };
        WireLoad {
            transactions: frames.len() as u32,
            bytes: frames.iter().sum(),
        }
    }

    /// Its time on a line of `timing` (ns): every frame's characters, and the silent interval
    /// that ends each frame, request and answer.
    pub fn on_line(&self, timing: &crate::services::io::line::LineTiming) -> u64 {
        timing.frame_ns(self.bytes as usize) + 2 * u64::from(self.transactions) * timing.silent_ns
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wire_load_of_the_trijoint_station() {
        // 18 coils, 18 discrete inputs, 2 input registers, 3 holding registers.
        let sizes = [18, 18, 2, 3];
        assert_eq!(
            WireLoad::of(ExchangeMode::Tables, sizes),
            WireLoad {
                transactions: 4,
                bytes: 76
            }
        );
        assert_eq!(
            WireLoad::of(ExchangeMode::Image, sizes),
            WireLoad {
                transactions: 1,
                bytes: 36
            }
        );
        assert_eq!(WireLoad::of(ExchangeMode::Tables, [0, 0, 2, 0]).transactions, 1);
    }
}
