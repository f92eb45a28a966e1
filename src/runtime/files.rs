//! Opening the files a user names (configuration, I/O map, scenario, trace) safely: only regular
//! files, opened so that a FIFO cannot block the open, and text read up to a bound, so that a
//! device like `/dev/zero` or a file of gigabytes is a clear error rather than a hang or an
//! out-of-memory abort.

use std::fs::{File, OpenOptions};
use std::io::{self, Read};
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::Path;

/// The most a configuration, I/O map or scenario file may hold (16 MiB; the shipped ones are a
/// few kB).
pub const MAX_TEXT_BYTES: u64 = 16 << 20;

/// What a non-regular file is, for messages.
pub fn kind(t: std::fs::FileType) -> &'static str {
    if t.is_dir() {
        "a directory"
    } else if t.is_fifo() {
        "a FIFO"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_socket() {
        "a socket"
    } else {
        "not a regular file"
    }
}

/// Opens `path` for reading if it is a regular file. The open does not block on a FIFO
/// (`O_NONBLOCK`, which a regular file ignores); anything else is refused with what it is.
pub fn open_regular(path: &Path) -> io::Result<File> {
    let file = OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)?;
    let t = file.metadata()?.file_type();
    if t.is_file() {
        Ok(file)
    } else {
        Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("{}: only a regular file can be read here", kind(t)),
        ))
    }
}

/// Replaces the file `path` with `text` so that a crash or a power cut leaves the old file or
/// the new one, whole: the text goes to `PATH.new`, which is flushed to the disk, then renamed
/// over `path`, and the directory is flushed too (the rename is on the disk only then).
pub fn replace_durably(path: &Path, text: &str) -> io::Result<()> {
    use std::io::Write;
    let mut temporary = path.as_os_str().to_owned();
    temporary.push(".new");
    let temporary = std::path::PathBuf::from(temporary);
    {
        let mut file = OpenOptions::new()
            .write(true)
            .create(true)
            .truncate(true)
            .mode(0o644)
            .open(&temporary)?;
        file.write_all(text.as_bytes())?;
        file.sync_all()?;
    }
    std::fs::rename(&temporary, path)?;
    let directory = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    File::open(directory)?.sync_all()
}

/// The contents of the regular file `path` (a leading byte order mark removed), refused if it
/// holds more than `limit` bytes.
pub fn read_text(path: &Path, limit: u64) -> io::Result<String> {
    let mut text = String::from_utf8(read_to_limit(open_regular(path)?, limit)?)
        .map_err(|_| io::Error::new(io::ErrorKind::InvalidData, "stream did not contain valid UTF-8"))?;
    // A byte order mark (Windows editors write one) is not part of the text.
    if text.starts_with('\u{feff}') {
        text.drain(..'\u{feff}'.len_utf8());
    }
    Ok(text)
}

/// The bytes of an opened file (see [`open_regular`]), refused if it holds more than `limit`.
pub fn read_to_limit(file: File, limit: u64) -> io::Result<Vec<u8>> {
    let too_large = |size: String| {
        io::Error::new(
            io::ErrorKind::InvalidData,
            format!("{size} is more than the {} MiB such a file may hold", limit >> 20),
        )
    };
    let size = file.metadata()?.len();
    if size > limit {
        return Err(too_large(format!("{size} bytes")));
    }
    let mut bytes = Vec::new();
    // The bound holds even if the file grows while it is read.
    file.take(limit + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return Err(too_large("the file".into()));
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_directories_and_fifos_are_refused_without_blocking() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("fifo");
        assert!(
            std::process::Command::new("mkfifo")
                .arg(&fifo)
                .status()
                .unwrap()
                .success()
        );
        for (path, what) in [
            (Path::new("/dev/zero"), "a character device"),
            (dir.path(), "a directory"),
            (fifo.as_path(), "a FIFO"),
        ] {
            let e = read_text(path, MAX_TEXT_BYTES).unwrap_err();
            assert_eq!(
                e.to_string(),
                format!("{what}: only a regular file can be read here"),
                "{}",
                path.display()
            );
        }
    }

    #[test]
    fn a_file_over_the_bound_is_refused_and_one_within_it_is_read() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("big.json");
        std::fs::write(&path, vec![b' '; (2 << 20) + 1]).unwrap();
        let e = read_text(&path, 2 << 20).unwrap_err();
        assert_eq!(
            e.to_string(),
            "2097153 bytes is more than the 2 MiB such a file may hold"
        );
        std::fs::write(&path, "{}").unwrap();
        assert_eq!(read_text(&path, 2 << 20).unwrap(), "{}");
    }
}
