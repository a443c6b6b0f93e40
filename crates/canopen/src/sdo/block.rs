//! The mechanics of block transfers (CiA 301 §7.2.4.3.8–15) that the client
//! and the server share: cutting a value into the segments of a block on the
//! sending side, and on the receiving side tracking sequence numbers, deciding
//! when to acknowledge, and which sequence number to acknowledge.

use super::wire::{BlockSegment, MAX_BLOCK_SIZE, SEGMENT_LEN, segment_count};

/// Whether a block size from the peer is one CiA 301 allows (1–127).
pub(super) fn valid_block_size(block_size: u8) -> bool {
    (1..=MAX_BLOCK_SIZE).contains(&block_size)
}

/// The segments of the block that starts with segment `first` (0-based over
/// the whole value): at most `block_size`, numbered from 1, the value's final
/// segment marked last.
pub(super) fn segments(data: &[u8], first: usize, block_size: u8) -> Vec<BlockSegment> {
    let total = segment_count(data.len());
    let count = total.saturating_sub(first).min(usize::from(block_size));
    (0..count)
        .map(|i| {
            let segment = first + i;
            let start = (segment * SEGMENT_LEN).min(data.len());
            let end = (start + SEGMENT_LEN).min(data.len());
            BlockSegment::new(i as u8 + 1, segment + 1 == total, &data[start..end])
        })
        .collect()
}

/// `n` of the end frame: bytes of the final segment that carry no data (7
/// for an empty value, whose single segment carries none).
pub(super) fn unused_in_last(len: usize) -> u8 {
    (segment_count(len) * SEGMENT_LEN - len) as u8
}

/// What one received segment means for the receiver.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Received {
    /// The segment's data when it is the next one expected.
    pub accepted: Option<[u8; SEGMENT_LEN]>,
    /// Acknowledge now, with this sequence number (the last one received in
    /// order).
    pub ack: Option<u8>,
    /// The value's final segment arrived in order: the end frame comes next.
    pub complete: bool,
}

/// The receiving side of the blocks of one transfer.
///
/// Segments count only in order: a segment whose number is not the next one
/// expected is dropped, and the acknowledgement at the end of the block names
/// the last one that arrived in order, so that the sender starts its next
/// block right after it (CiA 301: "ackseq", the sender retransmits from
/// there).
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct BlockReceiver {
    block_size: u8,
    last_good: u8,
    /// A segment of the current block has arrived, so the sender is at work
    /// and a silence means a lost segment rather than a slow start.
    seen: bool,
    /// An acknowledgement went out on the sub-block timeout and nothing has
    /// arrived in order since.
    rescued: bool,
    /// Since that acknowledgement, only segment 1 (the start of the resent
    /// block) counts: the rest of the old block may still be on its way, late
    /// rather than lost, and its final segment must not trigger a second
    /// acknowledgement, which the sender would take for the answer to its
    /// resent block and so send that block twice.
    resynchronising: bool,
}

impl BlockReceiver {
    pub(super) fn new(block_size: u8) -> Self {
        Self {
            block_size,
            last_good: 0,
            seen: false,
            rescued: false,
            resynchronising: false,
        }
    }

    pub(super) fn block_size(&self) -> u8 {
        self.block_size
    }

    /// Takes one segment; `Err` when its sequence number cannot be in a
    /// block of this size (0, or above the block size).
    pub(super) fn receive(&mut self, segment: &BlockSegment) -> Result<Received, ()> {
        if segment.seqno == 0 || segment.seqno > self.block_size {
            return Err(());
        }
        if self.resynchronising {
            if segment.seqno != 1 {
                return Ok(Received {
                    accepted: None,
                    ack: None,
                    complete: false,
                });
            }
            self.resynchronising = false;
        }
        self.seen = true;
        let in_order = segment.seqno == self.last_good + 1;
        if in_order {
            self.last_good = segment.seqno;
            self.rescued = false;
        }
        let complete = in_order && segment.last;
        // The block ends with its last number or with the value's last
        // segment, whether or not it came in order: an out-of-order one means
        // something in between was lost, and the acknowledgement says where
        // to resume.
        let ack = (segment.seqno == self.block_size || segment.last).then_some(self.last_good);
        if ack.is_some() {
            self.next_block();
        }
        Ok(Received {
            accepted: in_order.then_some(segment.data),
            ack,
            complete,
        })
    }

    /// Whether a silence now calls for [`BlockReceiver::rescue`] rather than
    /// for giving up.
    pub(super) fn wants_rescue(&self) -> bool {
        self.seen && !self.rescued
    }

    /// The sub-block timeout: the block's final segment did not arrive (lost,
    /// or dropped by a full receive queue), so acknowledge what did and let
    /// the sender resume from there, as CANopenNode does, instead of
    /// aborting the whole transfer. Once per stall; `None` when the sender
    /// has shown no sign of life since the last rescue.
    pub(super) fn rescue(&mut self) -> Option<u8> {
        if !self.wants_rescue() {
            return None;
        }
        let ackseq = self.last_good;
        self.next_block();
        self.rescued = true;
        self.resynchronising = true;
        Some(ackseq)
    }

    fn next_block(&mut self) {
        self.last_good = 0;
        self.seen = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seg(seqno: u8, last: bool) -> BlockSegment {
        BlockSegment::new(seqno, last, &[seqno; 7])
    }

    #[test]
    fn blocks_cut_the_value_into_numbered_segments() {
        let data: Vec<u8> = (0..20).collect();
        let block = segments(&data, 0, 2);
        assert_eq!(block.len(), 2);
        assert_eq!(block[0].encode(), [0x01, 0, 1, 2, 3, 4, 5, 6]);
        assert_eq!(block[1].encode(), [0x02, 7, 8, 9, 10, 11, 12, 13]);
        let block = segments(&data, 2, 127);
        assert_eq!(block.len(), 1);
        assert_eq!(block[0].encode(), [0x81, 14, 15, 16, 17, 18, 19, 0]);
        assert_eq!(unused_in_last(20), 1);
        assert_eq!(segments(&[], 0, 5)[0].encode(), [0x81, 0, 0, 0, 0, 0, 0, 0]);
        assert_eq!(unused_in_last(0), 7);
        assert_eq!(unused_in_last(14), 0);
        assert!(segments(&data, 3, 127).is_empty());
    }

    #[test]
    fn the_receiver_acks_at_the_end_of_each_block() {
        let mut rx = BlockReceiver::new(3);
        let r = rx.receive(&seg(1, false)).unwrap();
        assert_eq!(
            (r.accepted.is_some(), r.ack, r.complete),
            (true, None, false)
        );
        rx.receive(&seg(2, false)).unwrap();
        let r = rx.receive(&seg(3, false)).unwrap();
        assert_eq!(r.ack, Some(3));
        let r = rx.receive(&seg(1, true)).unwrap();
        assert_eq!(
            (r.accepted.is_some(), r.ack, r.complete),
            (true, Some(1), true)
        );
    }

    #[test]
    fn a_gap_acks_the_last_segment_received_in_order() {
        let mut rx = BlockReceiver::new(4);
        rx.receive(&seg(1, false)).unwrap();
        let r = rx.receive(&seg(3, false)).unwrap();
        assert_eq!((r.accepted, r.ack), (None, None));
        let r = rx.receive(&seg(4, false)).unwrap();
        assert_eq!((r.accepted, r.ack), (None, Some(1)));
        // The resent block starts at 1 again.
        assert!(rx.receive(&seg(1, false)).unwrap().accepted.is_some());
        assert_eq!(rx.receive(&seg(0, false)), Err(()));
        assert_eq!(rx.receive(&seg(5, false)), Err(()));
    }

    #[test]
    fn rescue_acks_once_per_stall() {
        let mut rx = BlockReceiver::new(4);
        assert!(
            !rx.wants_rescue(),
            "nothing seen yet: the sender may be slow"
        );
        rx.receive(&seg(1, false)).unwrap();
        rx.receive(&seg(2, false)).unwrap();
        assert_eq!(rx.rescue(), Some(2));
        assert_eq!(rx.rescue(), None);
        rx.receive(&seg(1, false)).unwrap();
        assert_eq!(rx.rescue(), Some(1));
    }

    #[test]
    fn after_a_rescue_the_rest_of_the_old_block_is_ignored() {
        let mut rx = BlockReceiver::new(4);
        rx.receive(&seg(1, false)).unwrap();
        assert_eq!(rx.rescue(), Some(1));
        // Segments 2-4 of the old block were late, not lost.
        for seqno in 2..=4 {
            let r = rx.receive(&seg(seqno, false)).unwrap();
            assert_eq!((r.accepted, r.ack), (None, None), "{seqno}");
        }
        assert!(!rx.wants_rescue(), "no second rescue without progress");
        // The resent block.
        assert!(rx.receive(&seg(1, false)).unwrap().accepted.is_some());
        rx.receive(&seg(2, false)).unwrap();
        rx.receive(&seg(3, false)).unwrap();
        assert_eq!(rx.receive(&seg(4, false)).unwrap().ack, Some(4));
    }
}
