// A Fast DDS (eProsima, Debian's libfastrtps 2.9) subscriber of ROS 2's
// /odom for the interoperability test of `canodom replay --ros2` (#43).
//
// Two readers of `rt/odom` (`nav_msgs::msg::dds_::Odometry_`): one reliable,
// one best effort (ROS 2's default and sensor-data subscriptions). The type
// is taken as raw CDR (no fastddsgen in Debian): the header's stamp, the
// frames and the pose are read from the bytes as ROS 2's Odometry lays them.
// Loopback only: a UDPv4 transport bound to 127.0.0.1, builtin transports
// and multicast off, discovery by unicast to 127.0.0.1's well-known ports.
//
//   fastdds_subscriber DOMAIN SECONDS_AFTER_LAST
// prints `reader,sec,nanosec,frame,child,x,y,qz,qw` per sample on stdout,
// and exits once SECONDS_AFTER_LAST pass without a sample (after the first).

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/subscriber/qos/DataReaderQos.hpp>
#include <fastdds/dds/topic/TopicDataType.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastrtps/utils/IPLocator.h>

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

using namespace eprosima::fastdds::dds;
using eprosima::fastrtps::rtps::InstanceHandle_t;
using eprosima::fastrtps::rtps::IPLocator;
using eprosima::fastrtps::rtps::Locator_t;
using eprosima::fastrtps::rtps::SerializedPayload_t;

// A message as its serialized bytes, the 4-byte encapsulation header first.
class RawType : public TopicDataType {
public:
    explicit RawType(const char* name) {
        setName(name);
        m_typeSize = 64 * 1024;
        m_isGetKeyDefined = false;
    }
    bool serialize(void* data, SerializedPayload_t* payload) override {
        auto* v = static_cast<std::vector<uint8_t>*>(data);
        if (v->size() > payload->max_size) return false;
        std::memcpy(payload->data, v->data(), v->size());
        payload->length = static_cast<uint32_t>(v->size());
        return true;
    }
    bool deserialize(SerializedPayload_t* payload, void* data) override {
        auto* v = static_cast<std::vector<uint8_t>*>(data);
        v->assign(payload->data, payload->data + payload->length);
        return true;
    }
    std::function<uint32_t()> getSerializedSizeProvider(void* data) override {
        auto* v = static_cast<std::vector<uint8_t>*>(data);
        return [v]() { return static_cast<uint32_t>(v->size()); };
    }
    void* createData() override { return new std::vector<uint8_t>(); }
    void deleteData(void* data) override { delete static_cast<std::vector<uint8_t>*>(data); }
    bool getKey(void*, InstanceHandle_t*, bool) override { return false; }
};

// Little-endian CDR reading, alignment counted from after the header.
struct Cdr {
    const std::vector<uint8_t>& b;
    size_t at = 4;
    bool ok = true;
    void align(size_t n) { at = 4 + ((at - 4 + n - 1) / n) * n; }
    template <typename T> T get() {
        align(sizeof(T));
        T v{};
        if (at + sizeof(T) > b.size()) { ok = false; return v; }
        std::memcpy(&v, b.data() + at, sizeof(T));
        at += sizeof(T);
        return v;
    }
    std::string str() {
        uint32_t n = get<uint32_t>();
        if (!ok || n == 0 || at + n > b.size()) { ok = false; return {}; }
        std::string s(reinterpret_cast<const char*>(b.data() + at), n - 1);
        at += n;
        return s;
    }
};

int main(int argc, char** argv) {
    if (argc < 3) {
        std::fprintf(stderr, "usage: %s DOMAIN SECONDS_AFTER_LAST\n", argv[0]);
        return 2;
    }
    const int domain = std::atoi(argv[1]);
    const double idle_s = std::atof(argv[2]);

    DomainParticipantQos pqos;
    pqos.name("canodom_fastdds_test");
    pqos.transport().use_builtin_transports = false;
    auto udp = std::make_shared<eprosima::fastdds::rtps::UDPv4TransportDescriptor>();
    udp->interfaceWhiteList.emplace_back("127.0.0.1");
    pqos.transport().user_transports.push_back(udp);
    auto& builtin = pqos.wire_protocol().builtin;
    // A unicast metatraffic locator of our own: no default multicast one.
    Locator_t meta;
    IPLocator::setIPv4(meta, 127, 0, 0, 1);
    meta.port = 0;  // the participant's well-known port
    builtin.metatrafficUnicastLocatorList.push_back(meta);
    Locator_t user;
    IPLocator::setIPv4(user, 127, 0, 0, 1);
    user.port = 0;
    pqos.wire_protocol().default_unicast_locator_list.push_back(user);
    // Initial peers: the well-known SPDP unicast ports of participants 0..9 on 127.0.0.1.
    for (int pid = 0; pid < 10; ++pid) {
        Locator_t peer;
        IPLocator::setIPv4(peer, 127, 0, 0, 1);
        peer.port = 7400 + 250 * domain + 10 + 2 * pid;
        builtin.initialPeersList.push_back(peer);
    }
    builtin.avoid_builtin_multicast = true;

    DomainParticipant* dp = DomainParticipantFactory::get_instance()->create_participant(domain, pqos);
    if (dp == nullptr) {
        std::fprintf(stderr, "fastdds: the participant could not be created\n");
        return 1;
    }
    TypeSupport type(new RawType("nav_msgs::msg::dds_::Odometry_"));
    type.register_type(dp);
    Topic* topic = dp->create_topic("rt/odom", type.get_type_name(), TOPIC_QOS_DEFAULT);
    Subscriber* sub = dp->create_subscriber(SUBSCRIBER_QOS_DEFAULT);
    DataReaderQos rq = DATAREADER_QOS_DEFAULT;
    rq.history().kind = KEEP_LAST_HISTORY_QOS;
    rq.history().depth = 100;
    rq.durability().kind = VOLATILE_DURABILITY_QOS;
    rq.reliability().kind = RELIABLE_RELIABILITY_QOS;
    DataReader* reliable = sub->create_datareader(topic, rq);
    rq.reliability().kind = BEST_EFFORT_RELIABILITY_QOS;
    DataReader* best_effort = sub->create_datareader(topic, rq);
    if (topic == nullptr || reliable == nullptr || best_effort == nullptr) {
        std::fprintf(stderr, "fastdds: the topic or a reader could not be created\n");
        return 1;
    }
    std::fprintf(stderr, "fastdds: subscribed to rt/odom on domain %d\n", domain);

    using clock = std::chrono::steady_clock;
    auto last = clock::now();
    bool any = false;
    std::vector<uint8_t> data;
    SampleInfo info;
    const auto start = clock::now();
    while (true) {
        bool got = false;
        for (auto [name, r] : {std::pair{"reliable", reliable}, std::pair{"best_effort", best_effort}}) {
            while (r->take_next_sample(&data, &info) == ReturnCode_t::RETCODE_OK) {
                if (!info.valid_data) continue;
                got = true;
                Cdr c{data};
                int32_t sec = c.get<int32_t>();
                uint32_t nanosec = c.get<uint32_t>();
                std::string frame = c.str();
                std::string child = c.str();
                double x = c.get<double>(), y = c.get<double>();
                c.get<double>();  // z
                c.get<double>();  // qx
                c.get<double>();  // qy
                double qz = c.get<double>(), qw = c.get<double>();
                if (!c.ok) {
                    std::printf("%s,undecodable\n", name);
                    continue;
                }
                std::printf("%s,%d,%u,%s,%s,%.17g,%.17g,%.17g,%.17g\n", name, sec, nanosec,
                            frame.c_str(), child.c_str(), x, y, qz, qw);
            }
        }
        const auto now = clock::now();
        if (got) {
            any = true;
            last = now;
        }
        const double idle = std::chrono::duration<double>(now - last).count();
        if (any && idle > idle_s) break;
        if (!any && std::chrono::duration<double>(now - start).count() > 120) {
            std::fprintf(stderr, "fastdds: nothing received in 120 s\n");
            break;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    std::fflush(stdout);
    dp->delete_contained_entities();
    DomainParticipantFactory::get_instance()->delete_participant(dp);
    return any ? 0 : 1;
}
