// The JSON kept of job results: per tenant, bounded by bytes, the least
// recently used dropped first.
#include "service/http/rendered_results.hpp"

#include <gtest/gtest.h>

#include <memory>
#include <string>

namespace riccati::service {
namespace {

std::shared_ptr<const std::string> json_of(std::size_t bytes, char c) {
  return std::make_shared<const std::string>(bytes, c);
}

TEST(RenderedResults, ATenantFindsOnlyItsOwn) {
  RenderedResults kept(1000);
  kept.put("alpha", "job-1", json_of(10, 'a'));
  ASSERT_NE(kept.find("alpha", "job-1"), nullptr);
  EXPECT_EQ(*kept.find("alpha", "job-1"), std::string(10, 'a'));
  EXPECT_EQ(kept.find("beta", "job-1"), nullptr);
  EXPECT_EQ(kept.find("alpha", "job-2"), nullptr);
  kept.erase("alpha", "job-1");
  EXPECT_EQ(kept.find("alpha", "job-1"), nullptr);
  EXPECT_EQ(kept.bytes(), 0u);
}

TEST(RenderedResults, TheLeastRecentlyUsedGoFirstAndTheBoundHolds) {
  RenderedResults kept(100);
  kept.put("t", "a", json_of(40, 'a'));
  kept.put("t", "b", json_of(40, 'b'));
  ASSERT_NE(kept.find("t", "a"), nullptr);  // a is now the most recent
  kept.put("t", "c", json_of(40, 'c'));     // 120 > 100: b goes
  EXPECT_NE(kept.find("t", "a"), nullptr);
  EXPECT_EQ(kept.find("t", "b"), nullptr);
  EXPECT_NE(kept.find("t", "c"), nullptr);
  EXPECT_EQ(kept.bytes(), 80u);
  EXPECT_EQ(kept.size(), 2u);
  // One over the whole bound is not kept, and takes nothing out.
  kept.put("t", "huge", json_of(101, 'h'));
  EXPECT_EQ(kept.find("t", "huge"), nullptr);
  EXPECT_EQ(kept.size(), 2u);
  // Put again under the same key: replaced, counted once.
  kept.put("t", "a", json_of(10, 'A'));
  EXPECT_EQ(*kept.find("t", "a"), std::string(10, 'A'));
  EXPECT_EQ(kept.bytes(), 50u);
}

TEST(RenderedResults, AKeptJsonOutlivesItsEviction) {
  RenderedResults kept(50);
  kept.put("t", "a", json_of(40, 'a'));
  const auto held = kept.find("t", "a");  // being sent
  kept.put("t", "b", json_of(40, 'b'));   // a evicted meanwhile
  EXPECT_EQ(kept.find("t", "a"), nullptr);
  EXPECT_EQ(*held, std::string(40, 'a'));
}

}  // namespace
}  // namespace riccati::service
