// Segment attach/detach for the haptic loop and the event drain.
#include "tactus/haptic/supervisor.h"

#include <spdlog/spdlog.h>

#include <chrono>
#include <thread>

#include <signal.h>
#include <unistd.h>

#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"

namespace tactus::haptic {

Supervisor::Supervisor(HapticLoop& loop, std::string segment_name)
    : loop_(loop), name_(std::move(segment_name)) {
  shared::Segment::validateName(name_);
}

Supervisor::~Supervisor() {
  loop_.offerLink(nullptr);
  auto held = [this] {
    const AttachedSegment* in_use = loop_.linkInUse();
    return in_use != nullptr && (in_use == link_.get() || in_use == retired_.get());
  };
  // a ticking loop adopts the withdrawal within a period; a stopped one has let go already
  // (HapticLoop::stopped); a stuck one may hold the link for ever
  for (int i = 0; i < 250 && held(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(2));
  if (held()) {
    spdlog::error("the haptic tick still holds the link to segment '{}': leaving it mapped until "
                  "the process ends", name_);
    (void)link_.release();      // never freed while the tick may use it
    (void)retired_.release();
  }
}

const shared::Segment* Supervisor::segment() const {
  return link_ ? &link_->segment : nullptr;
}

void Supervisor::retire(std::unique_ptr<AttachedSegment> old) {
  loop_.offerLink(nullptr);
  retired_ = std::move(old);
}

void Supervisor::detach() {
  if (!link_) return;
  retire(std::move(link_));
  for (int i = 0; i < 500 && loop_.linkInUse() == retired_.get(); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
}

bool Supervisor::watchTick(std::int64_t now_ns) {
  const HapticLoop::TickProgress p = loop_.tickProgress(now_ns);
  // twice the watchdog: a device read that stalls for a while (tens of ms) is late, not stuck
  const auto bound_ns = static_cast<std::int64_t>(2e6 * loop_.settings().watchdog_ms);
  if (p.running_ns <= bound_ns) {
    if (stuck_) {
      spdlog::warn("the haptic tick is running again (it was stuck for at least {:.0f} ms)",
                   1e-6 * static_cast<double>(stuck_longest_ns_));
    }
    stuck_ = false;
    halt_device_ = -1;
    still_stuck_reported_ = false;
    return false;
  }
  stuck_longest_ns_ = p.running_ns;
  if (!stuck_) {
    stuck_ = true;
    if (p.device < 0) {
      // preempted between the tick's stamps, or stuck outside a device call: if it then sits in
      // a device call, the next poll asks that device to halt (below)
      spdlog::error("the haptic tick has been stuck for {:.0f} ms (watchdog {} ms), not in a "
                    "device call: the device keeps its last command",
                    1e-6 * static_cast<double>(p.running_ns), loop_.settings().watchdog_ms);
    }
  }
  if (p.device >= 0 && halt_device_ != p.device) {
    // once per device and episode: the first time the stuck tick is seen in this device's call
    halt_device_ = p.device;
    halt_requested_ns_ = p.running_ns;
    if (loop_.device(p.device).halt()) {
      spdlog::error("the haptic tick has been stuck for {:.0f} ms in device {}'s read or write "
                    "(the device contract forbids blocking): asked the device to halt; its force "
                    "fades out once the call returns",
                    1e-6 * static_cast<double>(p.running_ns), p.device);
    } else {
      spdlog::error("the haptic tick has been stuck for {:.0f} ms in device {}'s read or write "
                    "(the device contract forbids blocking) and the device cannot be halted: it "
                    "keeps rendering its last command; stop haptic_server (SIGTERM ends it after "
                    "a grace period) and fix the device backend",
                    1e-6 * static_cast<double>(p.running_ns), p.device);
    }
    return true;
  }
  // a device that took the halt but did not return from its call: say so once
  if (!still_stuck_reported_ && halt_device_ >= 0 && p.device == halt_device_ &&
      p.running_ns - halt_requested_ns_ > bound_ns) {
    spdlog::error("the haptic tick is still stuck in device {}'s read or write {:.0f} ms after "
                  "the halt request: the device does not honour halt and keeps rendering its "
                  "last command; stop haptic_server (SIGTERM ends it after a grace period) and "
                  "fix the device backend",
                  p.device, 1e-6 * static_cast<double>(p.running_ns - halt_requested_ns_));
    still_stuck_reported_ = true;
  }
  return true;
}

void Supervisor::poll() {
  watchTick(shared::monotonicNs());
  for (int i = 0; i < loop_.deviceCount(); ++i) {
    if (std::string d = loop_.device(i).takeDiagnostics(); !d.empty()) {
      spdlog::warn("device {}: {}", i, d);
    }
  }

  // free a retired link once the loop has published that it no longer holds it: retire()
  // withdrew the offer first, and the tick re-checks the offer after announcing a link, so a
  // linkInUse() other than the retired link now means the tick will never touch it again
  if (retired_ && loop_.linkInUse() != retired_.get()) retired_.reset();
  if (retired_) return;

  if (link_) {
    // A dead simulation's segment is kept until it is replaced or removed: the loop fades the
    // force out on stale snapshots and keeps writing stats that tools can read.
    if (link_->segment.stillCurrent()) {
      const bool alive = link_->segment.creatorAlive();
      if (alive != creator_alive_) {
        if (!alive) spdlog::warn("the simulation of segment '{}' stopped responding", name_);
        creator_alive_ = alive;
      }
      return;
    }
    spdlog::warn("segment '{}' was removed or replaced: detaching", name_);
    retire(std::move(link_));
    return;
  }

  shared::TryOpenResult r = shared::Segment::tryOpen(name_, shared::Access::kReadWrite);
  if (!r.ok()) {
    if (r.message != last_open_message_) {
      if (r.status == shared::OpenStatus::kAbsent || r.status == shared::OpenStatus::kInitializing) {
        spdlog::info("waiting for the simulation (segment '{}'): {}", name_, r.message);
      } else {
        spdlog::error("cannot attach to segment '{}': {}", name_, r.message);
      }
      last_open_message_ = r.message;
    }
    return;
  }
  last_open_message_.clear();
  if (!r.segment->creatorAlive()) return;  // a stale segment: wait for the simulation to replace it
  // one haptic process per segment (a second one would fight over the device samples): one
  // compare-exchange claims it, so two racing haptic_servers cannot both win
  const std::int64_t other = r.segment->claimHaptic(static_cast<std::int64_t>(::getpid()));
  if (other != 0) {
    throw SegmentError("segment '" + name_ + "' is already served by " +
                       (other > 0 ? "haptic_server pid " + std::to_string(other)
                                  : std::string("another haptic_server")) +
                       ": stop it first (scripts/stop.sh) or start this one with another "
                       "--segment");
  }
  link_ = std::make_unique<AttachedSegment>(std::move(*r.segment));
  // every new snapshot is prepared on this thread, never in the tick
  link_->preparer.start(loop_.settings().localModel());
  creator_alive_ = true;
  spdlog::info("attached to segment '{}' (generation {}, up to {} contacts / {} rows)", name_,
               link_->segment.generation(), link_->segment.capacity().max_contacts,
               link_->segment.capacity().max_rows);
  loop_.offerLink(link_.get());
}

int Supervisor::drainEvents() {
  int n = 0;
  shared::RtEvent e;
  while (loop_.events().tryPop(&e)) {
    ++n;
    switch (e.code) {
      case shared::kEventSnapshotStale:
        spdlog::warn("contact snapshot stale ({:.1f} ms old): fading the force out", 1e-6 * e.arg0);
        break;
      case shared::kEventSnapshotFresh:
        spdlog::info("contact snapshots fresh again (seq {}): forces back", e.arg0);
        break;
      case shared::kEventDeviceFault:
        spdlog::warn("device read fault: force faded out until the device recovers (device {})",
                     e.arg0);
        break;
      case kEventNonFinite:
        spdlog::warn("device returned NaN/Inf: sample ignored, force faded out (device {})",
                     e.arg1);
        break;
      case kEventUnusableOrientation:
        spdlog::warn("device returned an orientation that is not a unit quaternion (norm {:.3g}): "
                     "sample ignored, pose held, force faded out (device {})", e.arg0, e.arg1);
        break;
      case kEventDisengaged:
        spdlog::warn("forces of device {} disengaged: the last force ({:.3f} N) fades out; they "
                     "re-engage once the requested force is below {} N", e.arg0, e.arg1,
                     loop_.settings().engage_threshold_n);
        break;
      case kEventSnapshotFromTheFuture:
        spdlog::warn("contact snapshot stamped {:.1f} ms in the future: treated as stale",
                     1e-6 * e.arg0);
        break;
      case shared::kEventDeviceNoData:
        spdlog::info("device returned no new data: holding the last pose (device {})", e.arg0);
        break;
      case shared::kEventForceClamped:
        spdlog::info("force clamped: {:.2f} N requested, {:.2f} N rendered", e.arg0, e.arg1);
        break;
      case shared::kEventSolverNotConverged:
        spdlog::info("haptic NSGS not converged within its budget ({} sweeps, error {:.2e})",
                     e.arg0, e.arg1);
        break;
      case shared::kEventOverrun:
        spdlog::warn("haptic tick overran its period by {:.1f} us", 1e-3 * e.arg0);
        break;
      default:
        spdlog::info("haptic event: {} ({}, {})", eventName(e.code), e.arg0, e.arg1);
        break;
    }
  }
  return n;
}

}  // namespace tactus::haptic
