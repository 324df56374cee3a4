#pragma once
// What changes over the fade time (docs/client.md, "A slot's life"): each slot's weight, and the
// LoD bias a frame draws with. Both follow the runtime's clock (Runtime::set_time), so that
// every renderer, and a test without one, sees the same fades. Owned by the page cache
// (Residency) and the runtime; render thread only.
//
// A slot's weight is 255 when its page is drawn as it is, 0 when it is drawn as what is above it
// (its nearest resident ancestor), and in between a blend of the two (docs/renderer.md, "Blending
// in"). It moves linearly over the fade time: from 0 to 255 for a page that arrives, from where it
// is to 0 for one that leaves, from where it is back to 255 for a leaving one that stays.
#include <cstdint>
#include <vector>

#include "tessera/client/page.hpp"
#include "tessera/client/upload.hpp"  // SlotWeight

namespace tessera::client {

class SlotFades {
public:
    // `slots` weights, all full; fade_s 0: no fades (every call below does nothing, and leave()
    // is never called: pages leave at once).
    SlotFades(std::uint32_t slots, double fade_s);
    bool enabled() const { return fade_s_ > 0; }
    double fade_seconds() const { return fade_s_; }

    // The clock, seconds, never decreasing: the time of the frame the next weights are drawn in.
    // Moves every fading weight to `now`; appends the slots whose page has faded out to `gone`.
    void advance(double now, std::vector<SlotId>& gone);

    // A page was written into `slot`: drawn from weight 0 now, rising.
    void arrive(SlotId slot);
    // The page in `slot` leaves: falling from where it is.
    void leave(SlotId slot);
    // The page leaving `slot` stays: rising from where it is.
    void keep(SlotId slot);
    // `slot` holds no page any more: full weight, not fading (nothing samples it).
    void release(SlotId slot);

    std::uint8_t weight(SlotId slot) const { return weights_[slot]; }
    bool falling(SlotId slot) const;
    std::size_t fading() const { return fading_.size(); }
    // Appends the weights changed since the last call, one entry per slot.
    void take_changes(std::vector<SlotWeight>& out);

private:
    struct Fading {
        SlotId slot;
        double start;      // seconds
        double from;       // the weight at `start`, 0..1
        bool out;          // falling (leaving), else rising
    };
    void start(SlotId slot, double from, bool out);
    void stop(SlotId slot);
    void set(SlotId slot, std::uint8_t w);

    double fade_s_ = 0;
    double now_ = 0;
    std::vector<std::uint8_t> weights_;
    std::vector<Fading> fading_;
    std::vector<std::uint32_t> fading_index_;  // per slot: its place in fading_ + 1; 0: not fading
    std::vector<std::uint8_t> changed_flag_;   // per slot: in changed_
    std::vector<SlotId> changed_;
};

// The LoD bias a frame draws with follows the requested one by at most one level per fade time,
// so that a bias step does not change the whole screen at once. fade_s 0: the requested bias.
class BiasGlide {
public:
    explicit BiasGlide(double fade_s) : fade_s_(fade_s) {}
    float advance(double now, float requested);
    float bias() const { return bias_; }

private:
    double fade_s_;
    bool started_ = false;
    double last_ = 0;
    float bias_ = 0;
};

}  // namespace tessera::client
