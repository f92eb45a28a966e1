//! Request and response PDUs of the simulated station, decoded and encoded here with every
//! length and quantity checked against the Modbus application protocol specification (V1.1b3).
//!
//! Why not tokio-modbus's server: its request decoder (0.17, the newest release) indexes out of
//! bounds on a write-multiple-coils request whose quantity exceeds 8 × its byte count, and
//! multiplies quantities that overflow in a debug build; one such frame ended `io-sim --serial`.
//! Nothing that arrives on a wire may panic anything, so the station decodes requests itself and
//! answers a malformed one with an exception. The request and response *types* are still
//! tokio-modbus's, so the station's logic does not depend on this module.

use std::borrow::Cow;

use tokio_modbus::{ExceptionCode, Request, Response};

/// Why a PDU was refused, and the exception code that says so to the client.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Refused {
    /// The request's function code.
    pub function: u8,
    /// The exception the station answers with.
    pub exception: ExceptionCode,
    /// What was wrong, for the log.
    pub why: &'static str,
}

/// The largest PDU a Modbus frame carries (253 bytes).
pub const MAX_PDU: usize = 253;

fn refuse(function: u8, exception: ExceptionCode, why: &'static str) -> Refused {
    Refused {
        function,
        exception,
        why,
    }
}

fn u16_at(pdu: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([pdu[at], pdu[at + 1]])
}

/// Decodes a request PDU (function code first). A PDU shorter or longer than its function
/// requires, a quantity out of the specification's range or a byte count that does not match
/// its quantity is refused with "illegal data value"; an unknown function with "illegal
/// function".
pub fn decode_request(pdu: &[u8]) -> Result<Request<'static>, Refused> {
    let Some(&function) = pdu.first() else {
        return Err(refuse(0, ExceptionCode::IllegalFunction, "empty PDU"));
    };
    let value = |why| refuse(function, ExceptionCode::IllegalDataValue, why);
    let exact = |len: usize| {
        if pdu.len() == len {
            Ok(())
        } else {
            Err(value("PDU length does not match the function"))
        }
    };
    let quantity_in = |q: u16, max: u16| {
        if (1..=max).contains(&q) {
            Ok(q)
        } else {
            Err(value("quantity out of range"))
        }
    };
    match function {
        0x01..=0x04 => {
            exact(5)?;
            let (address, q) = (u16_at(pdu, 1), u16_at(pdu, 3));
            Ok(match function {
                0x01 => Request::ReadCoils(address, quantity_in(q, 2000)?),
                0x02 => Request::ReadDiscreteInputs(address, quantity_in(q, 2000)?),
                0x03 => Request::ReadHoldingRegisters(address, quantity_in(q, 125)?),
                _ => Request::ReadInputRegisters(address, quantity_in(q, 125)?),
            })
        }
        0x05 => {
            exact(5)?;
            match u16_at(pdu, 3) {
                0xFF00 => Ok(Request::WriteSingleCoil(u16_at(pdu, 1), true)),
                0x0000 => Ok(Request::WriteSingleCoil(u16_at(pdu, 1), false)),
                _ => Err(value("a coil value is 0xFF00 or 0x0000")),
            }
        }
        0x06 => {
            exact(5)?;
            Ok(Request::WriteSingleRegister(u16_at(pdu, 1), u16_at(pdu, 3)))
        }
        0x0F => {
            let bytes = counted(pdu, 5).ok_or_else(|| value("PDU length does not match its byte count"))?;
            let q = quantity_in(u16_at(pdu, 3), 1968)?;
            if bytes.len() != usize::from(q).div_ceil(8) {
                return Err(value("byte count does not match the quantity of coils"));
            }
            let coils = (0..usize::from(q)).map(|i| bytes[i / 8] >> (i % 8) & 1 == 1).collect();
            Ok(Request::WriteMultipleCoils(u16_at(pdu, 1), Cow::Owned(coils)))
        }
        0x10 => {
            let bytes = counted(pdu, 5).ok_or_else(|| value("PDU length does not match its byte count"))?;
            let q = quantity_in(u16_at(pdu, 3), 123)?;
            if bytes.len() != 2 * usize::from(q) {
                return Err(value("byte count does not match the quantity of registers"));
            }
            Ok(Request::WriteMultipleRegisters(
                u16_at(pdu, 1),
                Cow::Owned(words(bytes)),
            ))
        }
        0x17 => {
            let bytes = counted(pdu, 9).ok_or_else(|| value("PDU length does not match its byte count"))?;
            let read = quantity_in(u16_at(pdu, 3), 125)?;
            let write = quantity_in(u16_at(pdu, 7), 121)?;
            if bytes.len() != 2 * usize::from(write) {
                return Err(value("byte count does not match the quantity of registers"));
            }
            Ok(Request::ReadWriteMultipleRegisters(
                u16_at(pdu, 1),
                read,
                u16_at(pdu, 5),
                Cow::Owned(words(bytes)),
            ))
        }
        _ => Err(refuse(function, ExceptionCode::IllegalFunction, "unsupported function")),
    }
}

/// The data of a PDU whose byte count sits at `at`, if the PDU ends exactly after it.
fn counted(pdu: &[u8], at: usize) -> Option<&[u8]> {
    let count = usize::from(*pdu.get(at)?);
    (pdu.len() == at + 1 + count).then(|| &pdu[at + 1..])
}

fn words(bytes: &[u8]) -> Vec<u16> {
    bytes
        .chunks_exact(2)
        .map(|w| u16::from_be_bytes([w[0], w[1]]))
        .collect()
}

/// How long a request PDU is, as far as the bytes that have arrived of it tell.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PduLen {
    /// The PDU has this many bytes, function code included.
    Known(usize),
    /// More bytes must arrive to tell.
    NeedMore,
    /// A function whose length cannot be known.
    Unknown,
}

/// How many bytes the request PDU starting at `pdu[0]` (the function code) has. RTU frames
/// carry no length, so a serial station finds the end of a request this way.
pub fn request_len(pdu: &[u8]) -> PduLen {
    let Some(&function) = pdu.first() else {
        return PduLen::NeedMore;
    };
    let with_count = |at: usize| {
        pdu.get(at)
            .map_or(PduLen::NeedMore, |c| PduLen::Known(at + 1 + usize::from(*c)))
    };
    match function {
        0x01..=0x06 => PduLen::Known(5),
        0x0F | 0x10 => with_count(5),
        0x17 => with_count(9),
        _ => PduLen::Unknown,
    }
}

/// Encodes the response to a request with `function` code: the response PDU, or the exception.
pub fn encode_response(function: u8, result: &Result<Response, ExceptionCode>, out: &mut Vec<u8>) {
    let response = match result {
        Ok(r) => r,
        Err(e) => {
            out.extend([function | 0x80, u8::from(*e)]);
            return;
        }
    };
    let words_out = |out: &mut Vec<u8>, fc: u8, words: &[u16]| {
        out.extend([fc, (2 * words.len()) as u8]);
        out.extend(words.iter().flat_map(|w| w.to_be_bytes()));
    };
    match response {
        Response::ReadCoils(bits) | Response::ReadDiscreteInputs(bits) => {
            let mut packed = vec![0u8; bits.len().div_ceil(8)];
            for (i, _) in bits.iter().enumerate().filter(|(_, b)| **b) {
                packed[i / 8] |= 1 << (i % 8);
            }
            out.extend([function, packed.len() as u8]);
            out.extend(packed);
        }
        Response::ReadHoldingRegisters(w)
        | Response::ReadInputRegisters(w)
        | Response::ReadWriteMultipleRegisters(w) => words_out(out, function, w),
        Response::WriteSingleCoil(a, v) => {
            out.push(function);
            out.extend(a.to_be_bytes());
            out.extend(if *v { [0xFF, 0x00] } else { [0x00, 0x00] });
        }
        Response::WriteSingleRegister(a, v)
        | Response::WriteMultipleCoils(a, v)
        | Response::WriteMultipleRegisters(a, v) => {
            out.push(function);
            out.extend(a.to_be_bytes());
            out.extend(v.to_be_bytes());
        }
        // The station answers only the functions decoded above.
        _ => out.extend([function | 0x80, u8::from(ExceptionCode::ServerDeviceFailure)]),
    }
}

/// CRC-16/MODBUS of `bytes` (sent little endian after an RTU frame).
pub fn crc16(bytes: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for b in bytes {
        crc ^= u16::from(*b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xA001 } else { crc >> 1 };
        }
    }
    crc
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn the_frame_that_panicked_tokio_modbus_is_an_exception() {
        // Write 16 coils at 0 with a byte count of 1: quantity > 8 × byte count.
        let e = decode_request(&[0x0F, 0, 0, 0, 16, 1, 0xFF]).unwrap_err();
        assert_eq!((e.function, e.exception), (0x0F, ExceptionCode::IllegalDataValue));
        assert_eq!(e.why, "byte count does not match the quantity of coils");
        // Quantities whose byte count overflows a u16 when doubled.
        let e = decode_request(&[0x10, 0, 0, 0x80, 0, 0]).unwrap_err();
        assert_eq!(e.why, "quantity out of range");
        let e = decode_request(&[0x17, 0x10, 0, 0, 8, 0x20, 0, 0x80, 1, 2, 0xAA, 0xBB]).unwrap_err();
        assert_eq!(e.why, "quantity out of range");
    }

    #[test]
    fn well_formed_requests_decode() {
        assert_eq!(
            decode_request(&[0x0F, 0, 2, 0, 10, 2, 0b0000_0101, 0b10]).unwrap(),
            Request::WriteMultipleCoils(
                2,
                Cow::Owned(vec![true, false, true, false, false, false, false, false, false, true])
            )
        );
        assert_eq!(
            decode_request(&[0x17, 0x10, 0, 0, 4, 0x20, 0, 0, 1, 2, 0xAA, 0xBB]).unwrap(),
            Request::ReadWriteMultipleRegisters(0x1000, 4, 0x2000, Cow::Owned(vec![0xAABB]))
        );
        assert_eq!(
            decode_request(&[0x2B, 0x0E]).unwrap_err().exception,
            ExceptionCode::IllegalFunction
        );
        assert_eq!(
            decode_request(&[0x03, 0, 0, 0]).unwrap_err().why,
            "PDU length does not match the function"
        );
    }

    #[test]
    fn responses_encode_as_the_specification_says() {
        let mut out = Vec::new();
        encode_response(2, &Ok(Response::ReadDiscreteInputs(vec![true; 9])), &mut out);
        assert_eq!(out, [2, 2, 0xFF, 0x01]);
        out.clear();
        encode_response(0x0F, &Err(ExceptionCode::IllegalDataAddress), &mut out);
        assert_eq!(out, [0x8F, 2]);
        assert_eq!(crc16(&[0x01, 0x03, 0x00, 0x00, 0x00, 0x0A]).to_le_bytes(), [0xC5, 0xCD]);
    }

    proptest! {
        /// Whatever bytes arrive, decoding answers (a request or a refusal) and never panics;
        /// a length it says it knows is the length it then accepts or refuses.
        #[test]
        fn no_pdu_panics_the_decoder(pdu in proptest::collection::vec(any::<u8>(), 0..300)) {
            let _ = decode_request(&pdu);
            if let PduLen::Known(n) = request_len(&pdu) {
                prop_assert!(n <= 5 + 1 + 255 + 4);
            }
        }

        /// Write-multiple-coils with any quantity and byte count: refused unless they match.
        #[test]
        fn coil_quantities_are_checked(q in any::<u16>(), count in any::<u8>()) {
            let mut pdu = vec![0x0F, 0, 0];
            pdu.extend(q.to_be_bytes());
            pdu.push(count);
            pdu.extend(std::iter::repeat_n(0xA5, usize::from(count)));
            let ok = (1..=1968).contains(&q) && usize::from(count) == usize::from(q).div_ceil(8);
            prop_assert_eq!(decode_request(&pdu).is_ok(), ok);
        }
    }
}
