// ContactGroups: the contact problem solved per group of coupled bodies (contact_groups.h).
#include "contact_groups.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "simulation_state.h"
#include "step_scratch.h"
#include "tactus/shared/clock.h"
#include "tactus/sim/tissue_contact.h"

namespace tactus::sim {
namespace {

// How bad a status is when groups are combined: any failure beats kConverged.
int severity(shared::NsgsStatus s) {
  switch (s) {
    case shared::NsgsStatus::kConverged: return 0;
    case shared::NsgsStatus::kMaxSweeps: return 1;
    case shared::NsgsStatus::kTimeBudget: return 2;
    case shared::NsgsStatus::kEmpty: return 3;
    case shared::NsgsStatus::kIllPosed: return 4;
    case shared::NsgsStatus::kNonFinite: return 5;
  }
  return 5;
}

}  // namespace

int ContactGroups::root(int body) {
  while (parent_[static_cast<std::size_t>(body)] != body) {
    int& up = parent_[static_cast<std::size_t>(body)];
    up = parent_[static_cast<std::size_t>(up)];   // path halving
    body = up;
  }
  return body;
}

void ContactGroups::find(const SimulationState& state, const StepScratch& scratch) {
  const int tissues = static_cast<int>(state.tissues.size());
  const int bodies = tissues + static_cast<int>(state.instruments.size());
  const int contacts = scratch.problem.contacts;
  parent_.resize(static_cast<std::size_t>(bodies));
  std::iota(parent_.begin(), parent_.end(), 0);
  label_.assign(static_cast<std::size_t>(contacts), 0);
  const auto unite = [&](int a, int b) {
    a = root(a);
    b = root(b);
    if (a != b) parent_[static_cast<std::size_t>(std::max(a, b))] = std::min(a, b);
  };
  const std::vector<Contact>& all = scratch.all_contacts;
  for (int t = 0; t < tissues; ++t) {
    const TissueScratch& tx = scratch.tissues[static_cast<std::size_t>(t)];
    const int own = std::max(0, static_cast<int>(tx.rows.row_offset.size()) - 1);
    for (int c = tx.contact_begin; c < tx.contact_begin + own; ++c) {
      label_[static_cast<std::size_t>(c)] = t;
      const int tool = all[static_cast<std::size_t>(c)].instrument;   // -1: an obstacle's
      if (tool >= 0) unite(t, tissues + tool);
    }
  }
  const PairRowsScratch& pairs = scratch.pair_rows;
  const int pair_contacts = std::max(0, static_cast<int>(pairs.row_offset.size()) - 1);
  for (int c = pairs.contact_begin; c < pairs.contact_begin + pair_contacts; ++c) {
    const TissueContactSpec& spec =
        state.tissue_contacts->spec(TissueContacts::pairOfId(all[static_cast<std::size_t>(c)].id));
    label_[static_cast<std::size_t>(c)] = spec.tissue_a;
    unite(spec.tissue_a, spec.tissue_b);
  }
  for (int& l : label_) l = root(l);
  assign(label_);
}

void ContactGroups::assign(const std::vector<int>& label) {
  const int contacts = static_cast<int>(label.size());
  const int labels = contacts == 0 ? 0 : *std::max_element(label.begin(), label.end()) + 1;
  group_of_label_.assign(static_cast<std::size_t>(labels), -1);
  group_.resize(label.size());
  count_ = 0;
  start_.assign(1, 0);
  for (std::size_t c = 0; c < label.size(); ++c) {
    int& g = group_of_label_[static_cast<std::size_t>(label[c])];
    if (g < 0) {
      g = count_++;
      start_.push_back(0);
    }
    group_[c] = g;
    ++start_[static_cast<std::size_t>(g) + 1];
  }
  for (std::size_t g = 1; g < start_.size(); ++g) start_[g] += start_[g - 1];
  fill_.assign(start_.begin(), start_.end() - 1);
  members_.resize(label.size());
  for (int c = 0; c < contacts; ++c) {
    members_[static_cast<std::size_t>(fill_[static_cast<std::size_t>(group_[static_cast<std::size_t>(c)])]++)] = c;
  }
}

void ContactGroups::markUnreachable(const std::vector<int>& instrument,
                                    std::vector<std::uint8_t>& out) {
  const auto contacts = group_.size();
  fill_.assign(static_cast<std::size_t>(count_), 0);   // per group: has an instrument contact
  for (std::size_t c = 0; c < contacts && c < instrument.size(); ++c) {
    if (instrument[c] >= 0) fill_[static_cast<std::size_t>(group_[c])] = 1;
  }
  out.resize(contacts);
  for (std::size_t c = 0; c < contacts; ++c) {
    out[c] = fill_[static_cast<std::size_t>(group_[c])] != 0 ? 0 : 1;
  }
}

shared::NsgsResult ContactGroups::solveGathered(const shared::ContactProblemView& problem, int g,
                                                const shared::NsgsSettings& settings,
                                                shared::NsgsWorkspace& workspace, double* f) {
  const int* members = groupContacts(g);
  const int size = groupSize(g);
  sub_row_offset_.assign(1, 0);
  sub_rows_.clear();
  for (int k = 0; k < size; ++k) {
    const int c = members[k];
    for (int r = problem.row_offset[c]; r < problem.row_offset[c + 1]; ++r) sub_rows_.push_back(r);
    sub_row_offset_.push_back(static_cast<int>(sub_rows_.size()));
  }
  const int m = static_cast<int>(sub_rows_.size());
  sub_w_.resize(static_cast<std::size_t>(m) * static_cast<std::size_t>(m));
  sub_delta_free_.resize(static_cast<std::size_t>(m));
  sub_f_.resize(static_cast<std::size_t>(m));
  sub_mu_.resize(static_cast<std::size_t>(size));
  for (int i = 0; i < m; ++i) {
    const double* wi = problem.W + static_cast<std::ptrdiff_t>(sub_rows_[static_cast<std::size_t>(i)]) * problem.ld;
    double* out = sub_w_.data() + static_cast<std::ptrdiff_t>(i) * m;
    for (int j = 0; j < m; ++j) out[j] = wi[sub_rows_[static_cast<std::size_t>(j)]];
    sub_delta_free_[static_cast<std::size_t>(i)] = problem.delta_free[sub_rows_[static_cast<std::size_t>(i)]];
    sub_f_[static_cast<std::size_t>(i)] = f[sub_rows_[static_cast<std::size_t>(i)]];
  }
  for (int k = 0; k < size; ++k) sub_mu_[static_cast<std::size_t>(k)] = problem.mu[members[k]];
  const shared::ContactProblemView sub =
      shared::denseProblemView(size, m, sub_row_offset_.data(), sub_w_.data(), m,
                               sub_delta_free_.data(), sub_mu_.data());
  const shared::NsgsResult res = solveChosen(sub, settings, workspace, sub_f_.data());
  for (int i = 0; i < m; ++i) f[sub_rows_[static_cast<std::size_t>(i)]] = sub_f_[static_cast<std::size_t>(i)];
  return res;
}

shared::NsgsResult ContactGroups::solveChosen(shared::ContactProblemView view,
                                              const shared::NsgsSettings& settings,
                                              shared::NsgsWorkspace& workspace, double* f) {
  if (view.blocks == nullptr && view.W != nullptr && view.contacts > 1) {
    if (view.rows > blocks_rows_ || view.contacts > blocks_contacts_) {
      blocks_rows_ = std::max(view.rows, blocks_rows_);
      blocks_contacts_ = std::max(view.contacts, blocks_contacts_);
      blocks_.reserve(blocks_rows_, blocks_contacts_);
    }
    view = shared::chooseStorage(view, blocks_);
    if (view.blocks != nullptr) ++solved_on_blocks_;
  }
  return shared::solveNsgs(view, settings, workspace, f);
}

shared::NsgsResult ContactGroups::solveGroup(const shared::ContactProblemView& problem, int g,
                                             const shared::NsgsSettings& settings,
                                             shared::NsgsWorkspace& workspace, double* f) {
  const int* members = groupContacts(g);
  const int size = groupSize(g);
  shared::NsgsResult res;
  if (members[size - 1] - members[0] + 1 == size) {
    // contiguous: W's diagonal block in place
    const int c0 = members[0];
    const int r0 = problem.row_offset[c0];
    sub_row_offset_.resize(static_cast<std::size_t>(size) + 1);
    const shared::ContactProblemView sub =
        shared::contiguousSubproblem(problem, c0, c0 + size, sub_row_offset_.data());
    sub_rows_.resize(static_cast<std::size_t>(sub.rows));
    std::iota(sub_rows_.begin(), sub_rows_.end(), r0);
    res = solveChosen(sub, settings, workspace, f + r0);
  } else {
    res = solveGathered(problem, g, settings, workspace, f);
  }
  // the group's part of the whole problem's error (workspace.delta: the group's W f + q)
  GroupNorms& n = norms_[static_cast<std::size_t>(g)];
  n.q2 = n.f2 = n.delta2 = 0.0;
  for (std::size_t i = 0; i < sub_rows_.size(); ++i) {
    const int r = sub_rows_[i];
    n.q2 += problem.delta_free[r] * problem.delta_free[r];
    n.f2 += f[r] * f[r];
    n.delta2 += workspace.delta[i] * workspace.delta[i];
  }
  const double scale = std::sqrt(std::max({n.q2, n.f2, n.delta2}));
  const double residual = res.error * (scale > 0.0 ? scale : 1.0);   // naturalMapError's rule
  n.residual2 = residual * residual;
  n.scale = scale;
  n.sweeps += res.sweeps;
  return res;
}

shared::NsgsResult ContactGroups::solve(const shared::ContactProblemView& problem,
                                        const shared::NsgsSettings& settings,
                                        shared::NsgsWorkspace& workspace, double* f) {
  solved_on_blocks_ = 0;
  if (count_ <= 1 || problem.W == nullptr || problem.blocks != nullptr) {
    return solveChosen(problem, settings, workspace, f);
  }
  const std::int64_t t0 = shared::monotonicNs();
  norms_.assign(static_cast<std::size_t>(count_), GroupNorms{});
  shared::NsgsSettings each = settings;
  each.delta_is_current = false;
  shared::NsgsResult all;
  all.status = shared::NsgsStatus::kConverged;
  all.sor = settings.sor;
  // the whole problem's residual and scale (naturalMapError's max(|q|, |f|, |delta|)) from the
  // groups' parts: W is zero between groups, so the whole delta is the groups' side by side
  struct Whole {
    double residual = 0.0, scale = 0.0;
    double error() const { return residual / (scale > 0.0 ? scale : 1.0); }
  };
  const auto whole = [&] {
    double r2 = 0.0, q2 = 0.0, f2 = 0.0, d2 = 0.0;
    for (const GroupNorms& n : norms_) {
      r2 += n.residual2;
      q2 += n.q2;
      f2 += n.f2;
      d2 += n.delta2;
    }
    return Whole{std::sqrt(r2), std::sqrt(std::max({q2, f2, d2}))};
  };
  // pass 0: every group to the tolerance on its own scale; later passes (rare: several groups
  // just under it): the groups above an equal share of the whole residual budget, to that share
  for (int pass = 0; pass < kMaxPasses; ++pass) {
    // raw residual allowed per group
    const double budget =
        pass > 0 ? settings.tolerance * whole().scale / std::sqrt(static_cast<double>(count_))
                 : 0.0;
    for (int g = 0; g < count_; ++g) {
      const GroupNorms& n = norms_[static_cast<std::size_t>(g)];
      if (pass > 0) {
        if (n.residual2 <= budget * budget) continue;
        each.tolerance = budget / (n.scale > 0.0 ? n.scale : 1.0);
      }
      if (settings.time_budget_ns > 0) {
        // what is left of the budget (at least one sweep per group)
        each.time_budget_ns = std::max<std::int64_t>(1, settings.time_budget_ns -
                                                            (shared::monotonicNs() - t0));
      }
      const shared::NsgsResult res = solveGroup(problem, g, each, workspace, f);
      if (severity(res.status) > severity(all.status)) all.status = res.status;
      all.sor = std::min(all.sor, res.sor);
      all.relaxations += res.relaxations;
      if (pass == 0) all.ill_posed_contacts += res.ill_posed_contacts;
    }
    if (all.status != shared::NsgsStatus::kConverged || whole().error() <= settings.tolerance) {
      break;
    }
  }
  for (const GroupNorms& n : norms_) all.sweeps = std::max(all.sweeps, n.sweeps);
  if (all.status == shared::NsgsStatus::kNonFinite) {
    std::fill(f, f + problem.rows, 0.0);   // as solveNsgs does on the whole problem
    all.error = std::numeric_limits<double>::infinity();
  } else {
    all.error = whole().error();
    if (all.status == shared::NsgsStatus::kConverged && !(all.error <= settings.tolerance)) {
      all.status = shared::NsgsStatus::kMaxSweeps;
    }
  }
  all.elapsed_ns = shared::monotonicNs() - t0;
  return all;
}

}  // namespace tactus::sim
