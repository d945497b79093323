//! Groups on disk: `<data>/groups/<label, percent-encoded>/group.json` (written atomically)
//! and `trace.jsonl` (the header, then one line per state, appended).

#[cfg(test)]
use std::collections::BTreeSet;
use std::fs::{self, File, OpenOptions};
use std::io::{BufRead, BufReader, BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use super::GroupDef;

/// Where groups are kept.
#[derive(Debug, Clone)]
pub struct GroupStore {
    dir: PathBuf,
}

/// Where a group's states are recorded: a file, or memory when the service keeps no store.
#[derive(Debug)]
pub enum TraceWriter {
    /// `trace.jsonl`.
    File(BufWriter<File>),
    /// The trace in memory (an in-memory service).
    Memory(String),
}

impl TraceWriter {
    /// A trace in memory starting with `header`.
    pub fn memory(header: &str) -> Self {
        Self::Memory(format!("{header}\n"))
    }

    /// Appends a state line.
    pub fn append(&mut self, line: &str) {
        match self {
            Self::File(w) => {
                if let Err(e) = writeln!(w, "{line}") {
                    tracing::error!("cannot record a group state: {e}");
                }
            }
            Self::Memory(s) => {
                s.push_str(line);
                s.push('\n');
            }
        }
    }

    /// Hands what was appended to the operating system (it survives a crash of the service).
    pub fn flush(&mut self) {
        if let Self::File(w) = self
            && let Err(e) = w.flush()
        {
            tracing::error!("cannot record group states: {e}");
        }
    }

    /// Flushes and syncs to disk (it survives a crash of the machine).
    pub fn sync(&mut self) {
        self.flush();
        if let Self::File(w) = self {
            let _ = w.get_ref().sync_data();
        }
    }

    /// The in-memory trace.
    pub fn text(&self) -> Option<&str> {
        match self {
            Self::Memory(s) => Some(s),
            Self::File(_) => None,
        }
    }
}

/// The most bytes of a group's directory name. A label may be 200 characters, and each byte
/// of one that is not ASCII alphanumeric takes three when percent-encoded: 200 `é` would be
/// 1,200 bytes, and file systems allow 255 (ext4, XFS, Btrfs, tmpfs).
const MAX_DIR_NAME: usize = 120;

/// A group's directory name: its label percent-encoded (bytes other than ASCII letters,
/// digits, `_` and `-`). One that would be longer than [`MAX_DIR_NAME`] is cut at an
/// escape's boundary and ends in `~` and a hash of the whole label (`~` is always escaped,
/// so no short name ends so). The label itself is read from `group.json`.
fn encode(label: &str) -> String {
    let pieces: Vec<String> = label
        .bytes()
        .map(|b| {
            if b.is_ascii_alphanumeric() || b == b'_' || b == b'-' {
                char::from(b).to_string()
            } else {
                format!("%{b:02X}")
            }
        })
        .collect();
    let whole: String = pieces.concat();
    if whole.len() <= MAX_DIR_NAME {
        return whole;
    }
    // The prefix leaves room for `~` and 16 hex digits.
    let mut out = String::new();
    for piece in &pieces {
        if out.len() + piece.len() > MAX_DIR_NAME - 17 {
            break;
        }
        out.push_str(piece);
    }
    format!("{out}~{:016x}", fnv1a(label.as_bytes()))
}

/// FNV-1a, 64 bits: stable across builds and platforms (unlike `std`'s hasher).
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

impl GroupStore {
    /// Groups under `dir` (created when needed).
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        Self { dir: dir.into() }
    }

    fn group_dir(&self, label: &str) -> PathBuf {
        self.dir.join(encode(label))
    }

    /// Writes `def` atomically.
    pub fn save(&self, def: &GroupDef) -> Result<(), String> {
        let dir = self.group_dir(&def.label);
        let json = serde_json::to_vec_pretty(def).map_err(|e| e.to_string())?;
        let tmp = dir.join("group.json.tmp");
        let write = || -> std::io::Result<()> {
            fs::create_dir_all(&dir)?;
            let mut f = File::create(&tmp)?;
            f.write_all(&json)?;
            f.sync_all()?;
            fs::rename(&tmp, dir.join("group.json"))?;
            File::open(&dir)?.sync_all()
        };
        write().map_err(|e| format!("{}: {e}", dir.display()))
    }

    /// The directory `label`'s group would be written to, if something is there already:
    /// a group that could not be loaded at start-up (a damaged `group.json`), which a new
    /// group of that label must not overwrite with its trace.
    pub fn occupied(&self, label: &str) -> Option<PathBuf> {
        let dir = self.group_dir(label);
        (dir.join("group.json").exists() || dir.join("trace.jsonl").exists()).then_some(dir)
    }

    /// A new group: its definition and a trace holding only the header.
    pub fn create(&self, def: &GroupDef) -> Result<TraceWriter, String> {
        let dir = self.group_dir(&def.label);
        // Two labels cut to one directory name (their hashes equal too) are refused, never
        // written over each other.
        if let Ok(bytes) = fs::read(dir.join("group.json"))
            && let Ok(other) = serde_json::from_slice::<GroupDef>(&bytes)
            && other.label != def.label
        {
            return Err(format!(
                "{}: already holds group {:?}",
                dir.display(),
                other.label
            ));
        }
        fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        let path = dir.join("trace.jsonl");
        let mut f = File::create(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        writeln!(f, "{}", def.header.line()).map_err(|e| e.to_string())?;
        f.sync_all().map_err(|e| e.to_string())?;
        self.save(def)?;
        self.writer(&def.label)
    }

    /// Appends to a group's trace.
    pub fn writer(&self, label: &str) -> Result<TraceWriter, String> {
        let path = self.group_dir(label).join("trace.jsonl");
        let f = OpenOptions::new()
            .append(true)
            .open(&path)
            .map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(TraceWriter::File(BufWriter::with_capacity(1 << 16, f)))
    }

    /// Forgets a group.
    pub fn remove(&self, label: &str) -> Result<(), String> {
        let dir = self.group_dir(label);
        match fs::remove_dir_all(&dir) {
            Ok(()) => Ok(()),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
            Err(e) => Err(format!("{}: {e}", dir.display())),
        }
    }

    /// A group's recorded trace.
    pub fn trace(&self, label: &str) -> Result<String, String> {
        let path = self.group_dir(label).join("trace.jsonl");
        fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// Every group: its definition and its state lines (the header left out). A torn last
    /// line (a crash while appending) is cut off the file.
    pub fn load_all(&self) -> Result<Vec<(GroupDef, Vec<String>)>, String> {
        let mut out = Vec::new();
        let entries = match fs::read_dir(&self.dir) {
            Ok(e) => e,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(out),
            Err(e) => return Err(format!("{}: {e}", self.dir.display())),
        };
        for entry in entries {
            let dir = entry.map_err(|e| e.to_string())?.path();
            let def_path = dir.join("group.json");
            if !def_path.is_file() {
                forget_unfinished(&dir);
                continue;
            }
            let def: GroupDef = match fs::read(&def_path)
                .map_err(|e| e.to_string())
                .and_then(|b| serde_json::from_slice(&b).map_err(|e| e.to_string()))
            {
                Ok(d) => d,
                Err(e) => {
                    tracing::error!("{}: {e}; the group is not loaded", def_path.display());
                    continue;
                }
            };
            let lines = read_lines(&dir.join("trace.jsonl"), &def)?;
            out.push((def, lines));
        }
        out.sort_by(|a, b| a.0.label.cmp(&b.0.label));
        Ok(out)
    }
}

/// A group directory without `group.json`. A creation writes the trace's header, then the
/// definition (atomically), then answers: one cut short by a crash left a directory no group
/// is loaded from, whose label every later creation was refused (409) with no word in the
/// log. Such remains (a header at most, perhaps `group.json.tmp`) are removed, and said; a
/// directory holding more (recorded states) is kept, and said.
fn forget_unfinished(dir: &Path) {
    if !dir.is_dir() {
        return;
    }
    let trace = dir.join("trace.jsonl");
    let states = fs::read(&trace).map_or(0, |bytes| {
        bytes
            .split(|&b| b == b'\n')
            .filter(|l| !l.is_empty())
            .count()
            .saturating_sub(1)
    });
    let only_ours = fs::read_dir(dir).is_ok_and(|entries| {
        entries.filter_map(Result::ok).all(|e| {
            matches!(
                e.file_name().to_str(),
                Some("trace.jsonl" | "group.json.tmp")
            )
        })
    });
    if states == 0 && only_ours {
        match fs::remove_dir_all(dir) {
            Ok(()) => tracing::warn!(
                "{}: removed the remains of a group creation a stop cut short (no group.json; it \
                 was never answered)",
                dir.display()
            ),
            Err(e) => tracing::error!(
                "{}: the remains of a group creation a stop cut short could not be removed: {e}",
                dir.display()
            ),
        }
    } else {
        tracing::error!(
            "{}: no group.json, so no group is loaded from it and its label cannot be created \
             again; restore group.json or remove the directory",
            dir.display()
        );
    }
}

/// The state lines of a trace; a last line without its newline or that does not parse is cut.
fn read_lines(path: &Path, def: &GroupDef) -> Result<Vec<String>, String> {
    let err = |e: std::io::Error| format!("{}: {e}", path.display());
    let mut file = match OpenOptions::new().read(true).write(true).open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            let mut f = File::create(path).map_err(err)?;
            writeln!(f, "{}", def.header.line()).map_err(err)?;
            return Ok(Vec::new());
        }
        Err(e) => return Err(err(e)),
    };
    let mut reader = BufReader::new(&mut file);
    let mut lines = Vec::new();
    let mut good_len = 0u64;
    let mut buf = String::new();
    let mut first = true;
    loop {
        buf.clear();
        let n = reader.read_line(&mut buf).map_err(err)?;
        if n == 0 {
            break;
        }
        // Lines are appended whole and flushed at batch ends, so only the last line can be
        // torn: one without its newline (a line with one was written whole). The lines are
        // parsed when the trace is replayed.
        if !buf.ends_with('\n') {
            tracing::warn!(
                "{}: cutting a torn last line (a crash while recording)",
                path.display()
            );
            break;
        }
        good_len += n as u64;
        if first {
            first = false;
            continue;
        }
        lines.push(buf.trim_end().to_owned());
    }
    drop(reader);
    let len = file.seek(SeekFrom::End(0)).map_err(err)?;
    if len != good_len {
        file.set_len(good_len).map_err(err)?;
        file.seek(SeekFrom::Start(good_len)).map_err(err)?;
        if good_len == 0 {
            writeln!(file, "{}", def.header.line()).map_err(err)?;
        }
    }
    Ok(lines)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_directory_name_fits_every_file_system_and_names_one_label() {
        assert_eq!(encode("g-1"), "g-1");
        assert_eq!(encode("a b/é"), "a%20b%2F%C3%A9");
        let long = [
            " ".repeat(200),
            "é".repeat(200),
            "é".repeat(150),
            format!("{}x", "é".repeat(150)),
            "x".repeat(200),
            format!("{}%", "x".repeat(118)),
        ];
        let names: BTreeSet<String> = long.iter().map(|l| encode(l)).collect();
        assert_eq!(names.len(), long.len(), "{names:#?}");
        for (label, name) in long.iter().zip(long.iter().map(|l| encode(l))) {
            assert!(name.len() <= MAX_DIR_NAME, "{label:?}: {name}");
            assert!(name.contains('~'), "{name}");
            // Cut at an escape's boundary: what precedes `~` is a run of whole escapes.
            let prefix = &name[..name.find('~').unwrap()];
            assert!(label.starts_with(&decode(prefix)), "{label:?}: {name}");
        }
    }

    /// A percent-encoded prefix back to the label's bytes.
    fn decode(encoded: &str) -> String {
        let mut bytes = Vec::new();
        let mut rest = encoded.as_bytes();
        while let Some((&b, tail)) = rest.split_first() {
            if b == b'%' {
                bytes.push(
                    u8::from_str_radix(std::str::from_utf8(&tail[..2]).unwrap(), 16).unwrap(),
                );
                rest = &tail[2..];
            } else {
                bytes.push(b);
                rest = tail;
            }
        }
        String::from_utf8(bytes).unwrap()
    }
}
