//! A hostile DAQ on loopback: a raw Modbus TCP responder whose every reply a test
//! scripts ([`HostileDaq::start`]), for the faults a real DAQ shows: accepting and
//! closing at once (a device at its client limit), wrong transaction ids, blocks
//! pinned at full scale, frozen or backwards sequences, no answer at all.
//!
//! It answers FC 03 / FC 04 requests for a block in the millgate acquisition layout
//! (`millgate_config::layout`) with the block the script gives for the time since the
//! DAQ started; anything else it reads and ignores.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use millgate_config::layout::{encode_block, BLOCK_REGISTERS};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::task::JoinHandle;
use tokio::time::Instant;

/// What the DAQ does with one request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Reply {
    /// Answer with this block (sequence number and raw i16 samples, 1..=120).
    Block {
        /// The block's sequence number.
        sequence: u16,
        /// Its raw samples.
        raw: Vec<i16>,
    },
    /// Answer with this block under another transaction id than the request's.
    WrongTransaction {
        /// The block's sequence number.
        sequence: u16,
        /// Its raw samples.
        raw: Vec<i16>,
    },
    /// Answer with a block header announcing this sequence and no samples (n = 0).
    Empty {
        /// The block's sequence number.
        sequence: u16,
    },
    /// Answer with this block cut to half the registers asked for.
    Short {
        /// The block's sequence number.
        sequence: u16,
        /// Its raw samples.
        raw: Vec<i16>,
    },
    /// Answer with this Modbus exception code (e.g. 0x04, server device failure).
    Exception(u8),
    /// Close the connection without answering.
    Close,
    /// Say nothing (the request is read and left unanswered).
    Silence,
}

/// What the DAQ saw.
#[derive(Debug, Default)]
pub struct DaqStats {
    connections: AtomicU64,
    requests: AtomicU64,
}

impl DaqStats {
    /// Connections accepted.
    pub fn connections(&self) -> u64 {
        self.connections.load(Ordering::Relaxed)
    }

    /// Requests read.
    pub fn requests(&self) -> u64 {
        self.requests.load(Ordering::Relaxed)
    }
}

type Script = Box<dyn FnMut(Duration) -> Reply + Send>;

/// A scripted DAQ serving on a loopback port until dropped.
#[derive(Debug)]
pub struct HostileDaq {
    address: std::net::SocketAddr,
    stats: Arc<DaqStats>,
    task: JoinHandle<()>,
}

impl HostileDaq {
    /// Serve on a free loopback port; each request is answered with
    /// `script(time since start)`.
    pub async fn start(
        script: impl FnMut(Duration) -> Reply + Send + 'static,
    ) -> std::io::Result<Self> {
        Self::serve(Some(Box::new(script))).await
    }

    /// Accept every connection and close it at once, before any request: a real
    /// device at its client limit.
    pub async fn accept_and_close() -> std::io::Result<Self> {
        Self::serve(None).await
    }

    async fn serve(script: Option<Script>) -> std::io::Result<Self> {
        let listener = TcpListener::bind("127.0.0.1:0").await?;
        let address = listener.local_addr()?;
        let stats = Arc::new(DaqStats::default());
        let script = script.map(|script| Arc::new(Mutex::new(script)));
        let started = Instant::now();
        let counted = Arc::clone(&stats);
        let task = tokio::spawn(async move {
            while let Ok((stream, _)) = listener.accept().await {
                counted.connections.fetch_add(1, Ordering::Relaxed);
                let Some(script) = script.clone() else {
                    drop(stream);
                    continue;
                };
                let counted = Arc::clone(&counted);
                tokio::spawn(answer(stream, script, counted, started));
            }
        });
        Ok(Self {
            address,
            stats,
            task,
        })
    }

    /// Where it listens.
    pub fn address(&self) -> std::net::SocketAddr {
        self.address
    }

    /// What it saw so far.
    pub fn stats(&self) -> &DaqStats {
        &self.stats
    }
}

impl Drop for HostileDaq {
    fn drop(&mut self) {
        self.task.abort();
    }
}

async fn answer(
    mut stream: TcpStream,
    script: Arc<Mutex<Script>>,
    stats: Arc<DaqStats>,
    started: Instant,
) {
    loop {
        let mut header = [0u8; 7];
        if stream.read_exact(&mut header).await.is_err() {
            return;
        }
        let length = usize::from(u16::from_be_bytes([header[4], header[5]]));
        let mut pdu = vec![0u8; length.saturating_sub(1)];
        if stream.read_exact(&mut pdu).await.is_err() {
            return;
        }
        stats.requests.fetch_add(1, Ordering::Relaxed);
        let reply = (script.lock().unwrap_or_else(|p| p.into_inner()))(started.elapsed());
        let function = pdu.first().copied().unwrap_or(0x04);
        let mut words = vec![0u16; usize::from(BLOCK_REGISTERS)];
        let mut transaction = [header[0], header[1]];
        match reply {
            Reply::Close => return,
            Reply::Silence => continue,
            Reply::Exception(code) => {
                let frame = [
                    header[0],
                    header[1],
                    0,
                    0,
                    0,
                    3,
                    header[6],
                    function | 0x80,
                    code,
                ];
                if stream.write_all(&frame).await.is_err() {
                    return;
                }
                continue;
            }
            Reply::Block { sequence, raw } => encode_block(sequence, &raw, &mut words),
            Reply::Empty { sequence } => words[0] = sequence,
            Reply::Short { sequence, raw } => {
                encode_block(sequence, &raw, &mut words);
                words.truncate(words.len() / 2);
            }
            Reply::WrongTransaction { sequence, raw } => {
                let wrong = u16::from_be_bytes(transaction).wrapping_add(7);
                transaction = wrong.to_be_bytes();
                encode_block(sequence, &raw, &mut words);
            }
        }
        let byte_count = (words.len() * 2) as u8;
        let mut frame = vec![transaction[0], transaction[1], 0, 0];
        frame.extend((3 + u16::from(byte_count)).to_be_bytes());
        frame.extend([header[6], function, byte_count]);
        for word in words {
            frame.extend(word.to_be_bytes());
        }
        if stream.write_all(&frame).await.is_err() {
            return;
        }
    }
}

/// A script streaming `raw` in blocks of `per_block` samples, one block every
/// `block_period`, numbered by `sequence(block index)`: what a DAQ does, with the
/// numbering a test chooses (frozen, going backwards...). The last block is held.
/// The stream starts at the first request: a gateway whose start-up a loaded machine
/// delays still gets it from its first block.
pub fn streaming(
    raw: Vec<i16>,
    per_block: usize,
    block_period: Duration,
    mut sequence: impl FnMut(u64) -> u16 + Send + 'static,
) -> impl FnMut(Duration) -> Reply + Send + 'static {
    let blocks = (raw.len() / per_block).max(1) as u64;
    let mut first_request = None;
    move |elapsed| {
        let elapsed = elapsed - *first_request.get_or_insert(elapsed);
        let index = (elapsed.as_secs_f64() / block_period.as_secs_f64()) as u64;
        let index = index.min(blocks - 1);
        let start = index as usize * per_block;
        Reply::Block {
            sequence: sequence(index),
            raw: raw[start..(start + per_block).min(raw.len())].to_vec(),
        }
    }
}
